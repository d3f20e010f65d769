"""Functions that build diagrams from systems, the scenarios and the command line."""
