"""Sensor models of the simulated vehicle (the onboard side never sees the truth they start from)."""
