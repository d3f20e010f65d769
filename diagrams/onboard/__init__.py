"""Onboard stacks and their parts, buildable on the simulated or the MAVLink vehicle."""
