"""The one atomic-write helper: all or nothing, under crashes, errors and concurrent writers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rdd.atomic import (
    TargetExistsError,
    atomic_dir,
    atomic_file,
    atomic_path,
    write_json_atomic,
    write_text_atomic,
)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_error_inside_keeps_old_file_and_leaves_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    write_json_atomic(target, {"v": 1})
    with pytest.raises(RuntimeError), atomic_file(target, "w") as fh:
        fh.write('{"v": 2, "half')
        raise RuntimeError("boom")
    assert json.loads(target.read_text()) == {"v": 1}
    assert _leftovers(tmp_path) == []


def test_simulated_crash_mid_write_keeps_old_file(tmp_path: Path) -> None:
    """A process killed (os._exit, no cleanup at all) while writing leaves the old content intact."""
    target = tmp_path / "out.txt"
    write_text_atomic(target, "old\n")
    code = textwrap.dedent(
        f"""
        import os
        from rdd.atomic import atomic_file
        with atomic_file({str(target)!r}, "w") as fh:
            fh.write("new but unfinished")
            fh.flush()
            os._exit(9)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    proc = subprocess.run([sys.executable, "-c", code], env=env, check=False)
    assert proc.returncode == 9
    assert target.read_text() == "old\n"
    # the crashed writer's temporary file may remain, but never under the target's name
    assert all(".tmp" in name for name in _leftovers(tmp_path))


def test_refuses_to_overwrite_when_asked(tmp_path: Path) -> None:
    target = tmp_path / "db.bin"
    target.write_bytes(b"keep")
    with pytest.raises(TargetExistsError, match="db.bin"):
        write_text_atomic(target, "x", overwrite=False)
    assert target.read_bytes() == b"keep"


def test_second_writer_without_overwrite_loses_cleanly(tmp_path: Path) -> None:
    """Two writers start before either finishes: the first to finish wins, the other raises."""
    target = tmp_path / "r.txt"
    with pytest.raises(TargetExistsError), atomic_file(target, "w", overwrite=False) as slow:
        slow.write("slow")
        with atomic_file(target, "w", overwrite=False) as fast:
            fast.write("fast")
    assert target.read_text() == "fast"
    assert _leftovers(tmp_path) == []


def test_files_follow_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        p = write_text_atomic(tmp_path / "a.txt", "x")
        with atomic_dir(tmp_path / "d") as d:
            (d / "f").write_text("y")
    finally:
        os.umask(old)
    assert (p.stat().st_mode & 0o777) == 0o644
    assert ((tmp_path / "d").stat().st_mode & 0o777) == 0o755


def test_atomic_dir_appears_whole_or_not_at_all(tmp_path: Path) -> None:
    target = tmp_path / "stage"
    with pytest.raises(ValueError), atomic_dir(target) as d:
        (d / "part").write_text("1")
        raise ValueError("fail mid-stage")
    assert not target.exists()
    assert _leftovers(tmp_path) == []
    with atomic_dir(target) as d:
        (d / "part").write_text("2")
    assert (target / "part").read_text() == "2"
    with pytest.raises(TargetExistsError):
        with atomic_dir(target):
            pass
    with atomic_dir(target, overwrite=True) as d:
        (d / "other").write_text("3")
    assert sorted(p.name for p in target.iterdir()) == ["other"]
    assert _leftovers(tmp_path) == []


def test_atomic_path_for_writers_that_need_a_name(tmp_path: Path):
    target = tmp_path / "fig.pdf"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".pdf" and tmp != target
        tmp.write_bytes(b"%PDF-1.4")
        assert not target.exists()  # nothing under the final name until the writer is done
    assert target.read_bytes() == b"%PDF-1.4"
    with pytest.raises(OSError), atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise OSError("disk full")
    assert target.read_bytes() == b"%PDF-1.4"
    assert _leftovers(tmp_path) == []
