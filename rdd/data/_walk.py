"""Finding dataset files below a folder, following symbolic links (datasets are often linked in)."""

from __future__ import annotations

import os
from pathlib import Path


def find_named(root: Path, filename: str) -> list[Path]:
    """Every file called ``filename`` below ``root``, through symlinked folders too (each real folder once)."""
    found, seen = [], set()
    for top, dirs, files in os.walk(root, followlinks=True):
        real = os.path.realpath(top)
        if real in seen:  # a link cycle, or one folder linked twice
            dirs[:] = []
            continue
        seen.add(real)
        if filename in files:
            found.append(Path(top) / filename)
    return found
