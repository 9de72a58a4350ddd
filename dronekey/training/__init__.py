"""Training and export (torch only): recipes, the training loop, data, checkpoints, ONNX in and out.

``train_cli``       ``dronekey-train``: arguments -> a ``Recipe`` and a ``Trainer``
``recipe``          the ``Recipe`` dataclass, the edge / paper / tiny presets, overrides, schedules
``trainer``         ``Trainer``: a run's setup, epochs, early stop, resume and presence stage
``objective``       the loss of one batch: the recipe's terms added up
``crop_stream``     where the crops come from (renders or COCO) and the batch stream
``coco_crops``      crops and labels from a COCO keypoint dataset (the real 2DroneKey layout)
``validation``      the fixed validation crops and the metrics of an epoch
``presence_refit``  the head-only presence stage after the epochs
``checkpoints``     network checkpoints (.pt) and the run folder's files (state.pt, history.json)
``warm_start``      ``--init-from``: a new run from a checkpoint's or an export's weights
``plots``           the run's plots (paper Figs. 5 and 8, validation per epoch)
``export_cli``      ``dronekey-export``: checkpoint -> ONNX, fp32 or int8
``export``          network -> fp32 ONNX with the runtime's metadata
``quantize``        fp32 ONNX -> static int8 (QDQ), calibrated on crops
``onnx_weights``    an exported model's weights read back into the network (fine-tuning)
``spread_fit``      ``dronekey-calibrate-spread``: the model's spread calibration, fitted and stored
``heading_cli``     ``dronekey-train-heading``: render, train and export the front/back classifier
``heading_data``    its data: sampler crops, the keypoint network's keypoints, front-up patches, labels
``heading_train``   its training loop and ONNX export
"""
