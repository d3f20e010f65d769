"""Controllers that produce `fc_command`."""
