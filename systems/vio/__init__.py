"""Visual-inertial odometry (issue 8, L Sec. 5.1): RGB-D front end, GTSAM sliding-window back end."""
