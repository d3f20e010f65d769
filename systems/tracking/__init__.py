"""Feedforward trackers and trajectory generation (M Sec. 4 and 6): goals -> full-state reference chi."""
