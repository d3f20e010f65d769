"""Hardware side: the MAVLink vehicle, real-time runner, camera drivers (later issues)."""
