"""Evaluation: the paper's metrics and tables, on rendered or recorded sequences.

``metrics``     OKS, SR, keypoint AP (pycocotools-equal), presence AUC (numpy only)
``keypoints``   keypoint AP / SR on fresh rendered crops
``pose``        the paper's Tab. VI 6DoF figures over sequences, through the pipeline
``pose_plot``   the paper's Fig. 10 for one sequence (matplotlib)
``robustness``  the LED x background x motion matrix and drone-free clutter, on reporting seeds
                (a package: matrix, seed sets, rendering, scoring, summary, report, run)
``cli``         ``dronekey-eval``
"""
