"""`python -m skeleton.host.cli`: what the `skel` entry point runs."""

import sys

from .commands import main

if __name__ == "__main__":   # imported alone (tests/test_layers.py), it runs nothing
    sys.exit(main())
