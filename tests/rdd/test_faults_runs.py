"""Faults of the run itself (issue 62): two runs on one output, SIGTERM, SIGKILL. Real processes and
real signals: a second run on an output that a live run is writing says so in one line and leaves the
first alone; SIGTERM stops a run with status 143 and no temporary copy left; after SIGKILL the rerun
removes what the killed run left and writes the same bytes as an uninterrupted run, with nothing
hidden in the published folder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from rdd.cli import main

ROOT = Path(__file__).resolve().parents[2]


def uniform_args(data: Path, out: Path) -> list[str]:
    return ["decompose", "--format", "native", "--data", str(data), "--decomposer", "uniform",
            "--option", "n_segments=3", "--out", str(out)]


def build_args(data: Path, out: Path) -> list[str]:
    return ["build-db", "--format", "native", "--data", str(data), "--encoder", "pixels", "--encoder-option",
            "size=4", "--no-cache", "--calibration-sample", "2", "--out", str(out)]


def spawn(hook: str, argv: list[str], flag: Path) -> subprocess.Popen:
    """``python -m rdd argv`` in a new process after ``hook`` (Python that slows a step and creates
    ``flag`` when the run reaches it)."""
    code = textwrap.dedent(hook) + f"\nimport sys\nfrom rdd.cli import main\nsys.exit(main({argv!r}))\n"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RDD_FLAG": str(flag)}
    return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_for(flag: Path, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + 120
    while not flag.exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline, "the run never reached the step"
        time.sleep(0.05)


# Each decomposed episode takes 0.3 s; the flag appears once the first episode is staged.
SLOW_DECOMPOSE = """
import os, time
from pathlib import Path
from rdd.decomposers.uniform import UniformDecomposer
original = UniformDecomposer.decompose
def slow(self, ep):
    if ep.name != "ep0":
        Path(os.environ["RDD_FLAG"]).touch()
    time.sleep(0.3)
    return original(self, ep)
UniformDecomposer.decompose = slow
"""


def hidden(folder: Path) -> list[str]:
    """Hidden names anywhere inside ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*"))


def test_second_run_on_the_same_output_says_so_and_leaves_the_first_alone(native_six, tmp_path, cli_fails):
    out, ref = tmp_path / "out.json", tmp_path / "ref.json"
    assert main(uniform_args(native_six, ref)) == 0
    first = spawn(SLOW_DECOMPOSE, uniform_args(native_six, out), tmp_path / "flag")
    try:
        wait_for(tmp_path / "flag", first)
        err = cli_fails(*uniform_args(native_six, out), expect=(f"--out {out}: another run (pid {first.pid}) is "
                                                                 "writing it", "give another --out"))
        assert "Traceback" not in err
        cli_fails(*uniform_args(native_six, out), "--force", expect=("another run",))
        assert first.wait(timeout=120) == 0, first.stderr.read()
    finally:
        first.kill()
        first.wait()
    assert out.read_bytes() == ref.read_bytes()
    assert not (tmp_path / ".out.json.parts").exists()
    # once the first is done, the output is an ordinary existing file again
    cli_fails(*uniform_args(native_six, out), expect=("already exists; pass --force",))


def test_second_build_db_on_the_same_database_says_so(native_six, tmp_path, cli_fails):
    hook = """
    import os, time
    from pathlib import Path
    import rdd.cli.build_db as b
    original = b.segment_entries
    def slow(*a, **k):
        Path(os.environ["RDD_FLAG"]).touch()
        time.sleep(0.3)
        return original(*a, **k)
    b.segment_entries = slow
    """
    db, ref = tmp_path / "db", tmp_path / "ref"
    assert main(build_args(native_six, ref)) == 0
    first = spawn(hook, build_args(native_six, db), tmp_path / "flag")
    try:
        wait_for(tmp_path / "flag", first)
        cli_fails(*build_args(native_six, db), expect=(f"--out {db}: another run (pid {first.pid})",))
        assert first.wait(timeout=120) == 0, first.stderr.read()
    finally:
        first.kill()
        first.wait()
    assert tree(db) == tree(ref) and hidden(tmp_path) == []


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_sigterm_during_the_database_write_leaves_no_copy(native_six, tmp_path):
    """SIGTERM while the database's folder is being written: status 143, the one line, no hidden
    copy of it beside --out (only the resumable parts); the rerun finishes it."""
    hook = """
    import os, time
    from pathlib import Path
    import rdd.database.model as m
    original = m.write_files
    def slow(tmp, *a, **k):
        original(tmp, *a, **k)
        Path(os.environ["RDD_FLAG"]).touch()
        time.sleep(60)
    m.write_files = slow
    """
    db = tmp_path / "db"
    proc = spawn(hook, build_args(native_six, db), tmp_path / "flag")
    try:
        wait_for(tmp_path / "flag", proc)
        assert len([p for p in tmp_path.iterdir() if p.name.startswith(".db.") and p.name.endswith(".tmp")]) == 1
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 143
    finally:
        proc.kill()
        proc.wait()
    err = proc.stderr.read()
    assert "terminated (build-db): stopped by SIGTERM; no partial output was written" in err, err
    assert "Traceback" not in err
    assert hidden(tmp_path) == [".db.parts"] and len(list((tmp_path / ".db.parts").iterdir())) == 6
    assert not (tmp_path / ".db.parts" / "owner").exists() and not db.exists()
    assert main(build_args(native_six, db)) == 0
    assert main(build_args(native_six, tmp_path / "ref")) == 0
    assert tree(db) == tree(tmp_path / "ref") and hidden(tmp_path) == []


def lerobot_args(src: Path, out: Path) -> list[str]:
    return ["decompose", "--format", "lerobot", "--data", str(src), "--decomposer", "uniform", "--option",
            "n_segments=3", "--fallback-instruction", "{task} ({index}/{count})", "--write-lerobot", str(out)]


def test_sigkill_while_a_video_is_staged_then_the_rerun_publishes_a_clean_copy(lerobot_factory, tmp_path):
    """SIGKILL while a video of the copy is half written: the rerun removes the killed run's temporary
    and the published copy equals an uninterrupted run's, nothing hidden in it."""
    hook = """
    import os, time
    from pathlib import Path
    import rdd.data.lerobot.write as w
    from rdd.atomic import atomic_path
    original = w.link_or_copy
    def half(src, dst, link):
        if src.suffix == ".mp4":
            with atomic_path(dst) as tmp:
                tmp.write_bytes(src.read_bytes()[:100])
                Path(os.environ["RDD_FLAG"]).touch()
                time.sleep(60)
        return original(src, dst, link)
    w.link_or_copy = half
    """
    src = lerobot_factory("v2.1")
    out = tmp_path / "copy"
    proc = spawn(hook, lerobot_args(src, out), tmp_path / "flag")
    try:
        wait_for(tmp_path / "flag", proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        proc.kill()
        proc.wait()
    assert any(p.name.endswith(".tmp.mp4") for p in (tmp_path / ".copy.parts").rglob("*"))
    assert main(lerobot_args(src, out)) == 0
    assert main(lerobot_args(src, tmp_path / "ref")) == 0
    assert hidden(out) == [] and tree(out) == tree(tmp_path / "ref")
    assert hidden(tmp_path) == []


def test_sigterm_during_the_lerobot_copy_removes_its_temporaries(lerobot_factory, tmp_path):
    """SIGTERM while the v2.1 source is laid out as v3.0 for the copy: status 143, the converted
    copy and every temporary removed (only the resumable parts stay), and the rerun finishes."""
    hook = """
    import os, time
    from pathlib import Path
    import rdd.data.lerobot.write as w
    original = w.convert_to_v30
    def slow(ds, out, **k):
        result = original(ds, out, **k)
        Path(os.environ["RDD_FLAG"]).touch()
        time.sleep(60)
        return result
    w.convert_to_v30 = slow
    """
    src = lerobot_factory("v2.1")
    out = tmp_path / "copy"
    proc = spawn(hook, [*lerobot_args(src, out), "--out", str(tmp_path / "seg.json")], tmp_path / "flag")
    try:
        wait_for(tmp_path / "flag", proc)
        assert any(".v30-" in name for name in hidden(tmp_path))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 143
    finally:
        proc.kill()
        proc.wait()
    assert "stopped by SIGTERM" in proc.stderr.read()
    assert not any(".v30-" in name or ".tmp" in name for name in hidden(tmp_path)), hidden(tmp_path)
    assert main([*lerobot_args(src, out), "--out", str(tmp_path / "seg.json")]) == 0
    assert hidden(tmp_path) == []


def test_main_gives_back_the_sigterm_handler_it_found(native_six, tmp_path):
    """In-process callers (a notebook, a harness) keep their own SIGTERM handling after a command."""
    mine = signal.getsignal(signal.SIGTERM)
    assert main(uniform_args(native_six, tmp_path / "x.json")) == 0
    assert signal.getsignal(signal.SIGTERM) is mine


def test_the_next_owner_removes_what_a_killed_run_left_beside_its_output(native_six, tmp_path):
    """What SIGKILL leaves mid-write (atomic temporaries beside the output: a database's whole copy,
    the old folder an overwrite moved aside, a half-written JSON) is removed by the next run on it."""
    left = [tmp_path / ".db.k1ll3d_x.tmp", tmp_path / ".db.k1ll3d_y.old", tmp_path / ".out.k1ll3d_z.tmp.json"]
    for path in left[:2]:
        (path / "previous").mkdir(parents=True)
        (path / "previous" / "begin.npy").write_bytes(b"x" * 1000)
    left[2].write_text("{\"half")
    other = tmp_path / ".other.k1ll3d_w.tmp"  # another output's: not this run's to remove
    other.mkdir()
    assert main(build_args(native_six, tmp_path / "db")) == 0
    assert main(uniform_args(native_six, tmp_path / "out.json")) == 0
    assert hidden(tmp_path) == [other.name]
