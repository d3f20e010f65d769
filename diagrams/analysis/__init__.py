"""Reading run folders: scores, summaries, identification and plots."""
