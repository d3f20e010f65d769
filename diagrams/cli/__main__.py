"""`python -m alight.diagrams.cli`: the `alight` command line."""
import sys

from alight.diagrams.cli import main

sys.exit(main())
