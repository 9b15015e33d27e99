"""``python -m rdd``."""

import sys

from rdd.cli import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m rdd"))  # usage lines name the program as it was run
