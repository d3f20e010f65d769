"""The commander's setpoint to the attitude, rate and mixer stages (internal to the autopilot)."""
from alight.systems.boundary import VectorLayout

# mode (CommandMode); q_WD (w, x, y, z); w_D body rates [rad/s]; thrust in [0, 1]; armed (0/1).
SETPOINT = VectorLayout("setpoint", [("mode", 1), ("q_WD", 4), ("w_D", 3), ("thrust", 1),
                                     ("armed", 1)])
