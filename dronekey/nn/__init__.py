"""The DroneKey network in torch (training and export only; the runtime never imports this).

``model``        DroneKeyNet: CNN + transformer encoder, gated key representations, heads
``backbones``    the ResNet-50 trunk and the edge backbone
``loss``         the pose-adaptive Mahalanobis loss and its schedules
``heatmap_aux``  training-only propeller heatmaps on the backbone's stride-8/16 maps
``heading_net``  the front/back classifier (a small CNN, antisymmetric under a half turn)
"""
