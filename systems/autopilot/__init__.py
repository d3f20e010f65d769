"""Emulation of what a Pixhawk running PX4 does below the companion computer: command checks,
arming and failsafe (commander), attitude control, body-rate PID control and the mixer."""
