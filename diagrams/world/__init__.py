"""The simulated vehicle and its world: plant, flight controller, target, cameras, ground."""
