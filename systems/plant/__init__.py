"""The simulated vehicle: rigid body, rotors, motors, drag and wind."""
