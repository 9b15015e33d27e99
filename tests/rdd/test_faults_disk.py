"""A full disk (issue 62), on a real one: a small tmpfs filled up, mounted where the test runs as
root (skipped with the reason otherwise). Each role gets one line naming the file and the role: the
output, staging, the database; an embedding cache that cannot be written is skipped with a warning
and the run goes on to the same output."""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from rdd.cli import main


@pytest.fixture
def full_disk(tmp_path) -> Iterator[Path]:
    """A 512 KiB tmpfs at ``tmp_path/full``; the test fills it with :func:`fill` when ready."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs (a real full disk) needs root")
    mount = tmp_path / "full"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mount)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(mount: Path) -> None:
    """Fill ``mount`` to the last byte."""
    fd = os.open(mount / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b"\1" * 4096):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)


def uniform(data: Path, out: Path) -> list[str]:
    return ["decompose", "--format", "native", "--data", str(data), "--decomposer", "uniform", "--option",
            "n_segments=3", "--out", str(out)]


def test_full_output_disk_names_the_file_and_its_role(native_six, tmp_path, full_disk, cli_fails):
    assert main(uniform(native_six, tmp_path / "a.json")) == 0
    fill(full_disk)
    cli_fails(*uniform(native_six, full_disk / "out.json"),
              expect=(f"error (decompose): no space left on device: cannot write {full_disk}/.out.json.parts/",
                      f"(staging: the resumable parts of --out {full_disk / 'out.json'}); free space beside --out"))
    cli_fails("evaluate", "--pred", f"u={tmp_path / 'a.json'}", "--gt", str(tmp_path / "a.json"),
              "--out", str(full_disk / "m.json"),
              expect=(f"error (evaluate): no space left on device: cannot write {full_disk / 'm.json'} (the output "
                      "--out); free space there or give another --out",))
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"]  # nothing half-written left


def test_full_database_disk_names_the_database(native_six, tmp_path, full_disk, cli_fails):
    build = ["build-db", "--format", "native", "--data", str(native_six), "--encoder", "pixels",
             "--encoder-option", "size=4", "--no-cache", "--calibration-sample", "2"]
    assert main([*build, "--out", str(tmp_path / "db")]) == 0
    shutil.copytree(tmp_path / "db", full_disk / "db")
    fill(full_disk)
    cli_fails("calibrate", "--db", str(full_disk / "db"), "--sample", "2",
              expect=(f"no space left on device: cannot write {full_disk / 'db' / 'manifest.json'} (the database "
                      f"--db {full_disk / 'db'})",))
    assert main(["decompose", "--format", "native", "--data", str(native_six), "--decomposer", "rdd", "--db",
                 str(full_disk / "db"), "--encoder-option", "size=4", "--no-cache",
                 "--out", str(tmp_path / "rdd.json")]) == 0  # unharmed, still read
    cli_fails(*build, "--out", str(full_disk / "db2"), expect=("no space left on device", str(full_disk)))


def test_a_full_cache_is_skipped_and_the_run_goes_on(native_six, tmp_path, full_disk, caplog):
    uvd = ["decompose", "--format", "native", "--data", str(native_six), "--decomposer", "uvd", "--encoder", "pixels",
           "--encoder-option", "size=4", "--option", "min_interval=3"]
    assert main([*uvd, "--no-cache", "--out", str(tmp_path / "ref.json")]) == 0
    (full_disk / "cache").mkdir()
    fill(full_disk)
    with caplog.at_level(logging.WARNING):
        assert main([*uvd, "--cache-dir", str(full_disk / "cache"), "--out", str(tmp_path / "out.json")]) == 0
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warned) == 1 and warned[0].startswith(f"embedding cache: cannot write {full_disk / 'cache'}/"), warned
    assert warned[0].endswith("(No space left on device); going on without caching it")
    assert (tmp_path / "out.json").read_bytes() == (tmp_path / "ref.json").read_bytes()


@pytest.mark.parametrize("raised", ["copy", "arrow"])
def test_a_full_disk_error_names_the_file_being_written(tmp_path, raised):
    """Without root as well: a copy's ENOSPC names its source first, a C library's has no errno;
    either way the error names the file being written (what the CLI's line reports)."""
    import errno

    from rdd.atomic import atomic_path

    target = tmp_path / "copy" / "episode.mp4"
    with pytest.raises(OSError) as caught, atomic_path(target) as tmp:
        if raised == "copy":
            raise OSError(errno.ENOSPC, "No space left on device", "/source/episode.mp4", str(tmp))
        raise OSError("IOError: error writing: No space left on device")
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(target)
    assert list(target.parent.iterdir()) == []
