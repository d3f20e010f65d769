"""Target perception: landing-pattern detection and tracking, the target EKF (L Sec. 5.2)."""
