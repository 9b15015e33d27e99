"""Deprecated names the command line keeps so that existing scripts and readers keep working.

The retrieval index was once called the *backend*. Everywhere it is now ``index``; these old
names are accepted (flags, options) or written (output keys) here and nowhere else, and will go in a
future major version:

* ``--backend`` for ``--index`` (``calibrate``, ``demo``);
* ``--option backend=...`` / ``backend_options=...`` for ``index`` / ``index_options`` (``decompose``);
* the key ``backend`` under which ``decompose``'s JSON ``config`` names the index (readers rely on it).
"""

from __future__ import annotations

import argparse

INDEX_FLAGS = ("--index", "--backend")
OPTION_ALIASES = {"backend": "index", "backend_options": "index_options"}
OUTPUT_KEYS = {"index": "backend"}


def add_index_arg(p: argparse.ArgumentParser, help: str) -> None:
    """``--index`` (and its deprecated spelling ``--backend``): exact, annoy or faiss."""
    p.add_argument(*INDEX_FLAGS, dest="index", default="exact", help=help)
