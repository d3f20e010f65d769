"""Feedforward trackers and trajectory generation (M Sec. 4 and 6): goal -> reference chi."""
