"""Tracking: measurements over time into tracks with stable ids.

``tracker``             tentative -> confirmed -> lost tracks, association, front/back log-odds
``position_filter``     constant-velocity Kalman filter of the position (filterpy)
``orientation_filter``  the orientation on the rotation manifold, with its covariance
"""
