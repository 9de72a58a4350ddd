"""Tracking: measurements over time into tracks with stable ids.

``tracker``             the tracker: association, gating, tentative -> confirmed -> lost
``tracker_config``      its thresholds and noise levels, checked
``track_record``        one track's filters, lifecycle counters and evidence
``orientation_update``  which IPPE solution a track follows, the rotation gate and resets
``heading``             front and back: the heading twin and its log-odds
``position_filter``     constant-velocity Kalman filter of the position (filterpy)
``orientation_filter``  the orientation on the rotation manifold, with its covariance
``motion_model``        both filters' transition and process noise, built once per time step
"""
