"""The managers of the flight stack, M Sec. 7 (as mrs_uav_managers): the control manager (M 7.2),
the constraint and gain manager (M 7.5) and the UAV manager (M 7.6)."""
