"""Synthetic 3DronePose-style sequences, the training sampler, and the sequence file formats.

``drone_look``, ``mesh``, ``renderer``   a drone's randomised look, its mesh, the rasteriser
``backgrounds``, ``effects``, ``flyers``  skies, photos and clutter; blur and noise; birds and clouds
``flight``, ``presets``                   flight models and the scripted Tab. I paths
``synthetic_sequence``                    one sequence of frames and ground truth
``provenance``                            which renderer drew it (code and libraries, in ``info``)
``sampler``                               training crops rendered on the fly (``CropSampler``)
``annotations``                           a frame's drone annotation (keypoints, pose, visibility)
``io/``                                   our §5.1 JSON (pydantic), the COCO reader, video and frames
``cli``                                   ``dronekey-sim``
"""
