"""Robustness of the whole pipeline to the drone's look, the background and the range
(``dronekey-eval robustness``).

The keypoint network once learned the renderer's LEDs instead of the drone. This evaluation renders
a fixed matrix of conditions on scene seeds that training and tuning never used, runs the daemon's
``TrackingPipeline`` (unchanged) over every sequence and reports, per condition, how well the drone
is found and posed and how often the tracker publishes something that is not the drone.

``matrix``     the conditions (LEDs x backgrounds x motions, far drones, drone-free) and their seeds
``seed_sets``  the tuning and reporting seed sets, kept apart and off the validation seed
``render``     the matrix rendered to disk, reused on a rerun
``scoring``    one sequence through the pipeline, scored frame by frame
``summary``    the figures pooled over a group of sequences
``report``     the table and the JSON
``run``        ``run_robustness``: all of the above, as ``dronekey-eval robustness`` runs it
``compare``    two runs' JSON side by side (``dronekey-eval compare``): pooled rows, sequences moved
"""
