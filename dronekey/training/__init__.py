"""Training and export (torch only): recipes, the loop, data, ONNX in and out.

``train``         ``dronekey-train``: the edge / paper / tiny recipes on renders or COCO
``coco_crops``    crops and labels from a COCO keypoint dataset (the real 2DroneKey layout)
``export``        ``dronekey-export``: checkpoint -> ONNX with the runtime's metadata, int8
``onnx_weights``  an exported model's weights read back into the network (fine-tuning)
"""
