"""Mission-level systems: what the vehicle should do next."""
