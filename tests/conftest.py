"""Real demonstration data for the tests that read it: found through ``RDD_TEST_DATA``, else skipped.

``RDD_TEST_DATA`` names a folder laid out as ``rlbench/open_drawer/all_variations/episodes/episodeN``
(RLBench's own format) and ``lerobot/<dataset>`` (LeRobot v2.1 / v3.0); see docs/testing.md.
Also ``unwritable``: a folder this process cannot create files in, for the tests of outputs; and
``processes``: the live process table, for the tests of how runs stop.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

ENV = "RDD_TEST_DATA"


@pytest.fixture
def real_data() -> Callable[[str], Path]:
    """``real_data("rlbench")``: that path under ``$RDD_TEST_DATA``, or skip the test saying why."""

    def find(rel: str) -> Path:
        root = os.environ.get(ENV)
        if not root:
            pytest.skip(f"real data: set {ENV} to a folder holding {rel}/ (docs/testing.md)")
        path = Path(root) / rel
        if not path.exists():
            pytest.skip(f"real data: {path} is absent ({ENV}={root})")
        return path

    return find


@pytest.fixture
def processes() -> Callable[[], list[tuple[int, int, int]]]:
    """``processes()``: (pid, parent pid, process group) of every live process (Linux /proc), else skip."""
    if not Path("/proc/self/stat").exists():
        pytest.skip("reads the process table from Linux /proc")

    def table() -> list[tuple[int, int, int]]:
        out = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                out.append((int(stat.parent.name), int(fields[1]), int(fields[2])))
        return out

    return table


@pytest.fixture
def unwritable(tmp_path) -> Path:
    """A folder this process cannot create files in (root ignores modes: then /sys, mounted read-only)."""
    if os.geteuid() != 0:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
        yield folder
        folder.chmod(0o755)
        return
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
    except OSError:
        yield Path("/sys")
        return
    os.close(fd)
    os.unlink(probe)
    pytest.skip("no folder here refuses a new file to root")
