"""Running: simulating, run folders, the runners of every command."""
