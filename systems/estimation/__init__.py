"""State estimation of the flight-stack paper (M Sec. 3, 7.1): the linear Kalman filter on the
decoupled model M(7)-(11), heading per M(3)-(5) and M(12)-(15), the bank of filters with its
arbiter (M Sec. 3.5) and the measurement adapters that feed it."""
