"""Work done episode by episode, staged beside the output, so a long run that stops resumes where it stopped.

A command over many episodes (``decompose``; ``build-db``'s embedding) writes each finished
episode's result at once, atomically, into a hidden folder beside its output (``.<out>.parts/``),
under a name made of the episode and a hash of the command's settings that affect results. A rerun
of the same command, after a crash, a Ctrl-C or a ``kill -9``, does only the episodes missing there
(a rerun with other settings finds none of its own); the output is assembled from the parts in
episode order, so it is the same bytes as an uninterrupted run's, and the folder is removed once
the output is written. Episodes are read, worked on and released one at a time.

One run owns an output at a time (:func:`claim`): a second run on the same output stops at once with
a line saying that another run (its pid) is writing it, so the two never share the staging folder.
The owner also removes what a killed earlier run left beside the output (hidden temporaries), and a
staged part that cannot be read back (truncated, damaged) is redone, with a warning.

``--workers N`` runs the episodes in N processes on this machine (spawned: each builds its own
components from the command's arguments, with cores // N torch threads), each taking the next
episode as it finishes one; one bar counts the whole job. ``--executor ray`` runs the same step
function as tasks on a Ray cluster instead (``rdd.batch.ray_executor``).
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rdd.atomic import leftovers, remove_temporaries, write_text_atomic
from rdd.data.episode import Episode
from rdd.errors import UsageError, interrupt_on_sigterm
from rdd.progress import EpisodeBar, show_progress

log = logging.getLogger(__name__)

# Arguments that do not change any episode's result: where outputs go, which episodes are chosen
# (a part is the result of one episode), the embedding cache (a cache, not an input), parallelism.
NOT_SETTINGS = frozenset({"out", "write_lerobot", "lerobot_version", "force", "workers", "executor", "ray_address",
                         "include", "exclude", "cache_dir",
                          "no_cache", "verbose", "func", "command"})


def digest(data: Any) -> str:
    """SHA-256 of ``data`` as canonical JSON (values JSON cannot hold are written as text)."""
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def settings_hash(args: argparse.Namespace, **extra: Any) -> str:
    """A hash of everything in ``args`` that affects an episode's result, and ``extra`` (what the
    components made of them: a database's fingerprint, an encoder's weights)."""
    fields = {k: v for k, v in vars(args).items() if k not in NOT_SETTINGS}
    return digest({"args": fields, **extra})


def parts_folder(out: Path) -> Path:
    """The hidden staging folder beside ``out`` (``.<name>.parts``, a long name shortened to fit)."""
    name = out.name
    if len(os.fsencode(name)) > 200:
        name = name[:80] + "-" + hashlib.sha256(os.fsencode(name)).hexdigest()[:16]
    return out.parent / f".{name}.parts"


OWNER = "owner"  # in the staging folder: the pid of the run that holds it


@contextlib.contextmanager
def claim(out: Path | None, flag: str) -> Iterator[None]:
    """Hold ``out`` (and its staging folder) for this run alone while the block runs; another run
    holding it is a UsageError naming it. The lock is the kernel's (``flock`` on the staging folder),
    so a killed run never leaves a stale one; once held, the temporaries a killed run left beside
    ``out`` and in the staging folder are removed."""
    if out is None:
        yield
        return
    folder = parts_folder(out)
    while True:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            owner = _read_owner(folder)
            raise UsageError(f"{flag} {out}: another run{owner} is writing it (its staging folder {folder} is "
                             f"in use); wait for it to finish, or give another {flag}") from None
        except OSError as exc:  # a filesystem without locks (some network mounts): go on unguarded
            log.warning("%s: cannot lock %s (%s); two runs on this output would not be kept apart",
                        flag, folder, exc.strerror)
        try:
            if os.stat(folder).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)  # the run that held it removed the folder meanwhile: lock the new one
    try:
        write_text_atomic(folder / OWNER, f"{os.getpid()}\n")
        for path in [*leftovers(out), *remove_temporaries(folder)]:
            if path.exists():
                shutil.rmtree(path) if path.is_dir() else path.unlink()
        yield
    finally:
        with contextlib.suppress(OSError):  # gone with the staging folder once the output is written
            (folder / OWNER).unlink()
        with contextlib.suppress(OSError):
            folder.rmdir()  # only when empty: no part was staged
        os.close(fd)


def _read_owner(folder: Path) -> str:
    try:
        return f" (pid {int((folder / OWNER).read_text())})"
    except (OSError, ValueError):
        return ""


@dataclass(frozen=True)
class Staging:
    """Where one command's per-episode parts go: ``folder``, names keyed by ``settings``."""

    folder: Path
    settings: str
    suffix: str = ".json"

    def path(self, index: int, episode: Episode, extra: Any = None) -> Path:
        """The part of the ``index``-th episode of the command's list (``extra``: what else its result
        depends on, e.g. the segments it embeds)."""
        key = digest([self.settings, int(index), episode.name, int(episode.num_frames), extra])
        return self.folder / f"{key[:40]}{self.suffix}"

    def remove(self) -> None:
        """Delete the staging folder (every part, of any settings): the output is written."""
        shutil.rmtree(self.folder, ignore_errors=True)


# A step does one episode's work and writes its part: step(state, part_path, episode, payload).
Step = Callable[[Any, Path, Episode, Any], None]
_STATE: Any = None  # a worker process's components, made once by its factory


def cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def set_torch_threads(n: int) -> None:
    if "torch" in sys.modules:  # torch only when a component uses it (encoders)
        sys.modules["torch"].set_num_threads(n)


def _worker_init(factory: Callable[..., Any], factory_args: tuple, threads: int) -> None:
    global _STATE
    interrupt_on_sigterm()  # a worker's finally blocks remove its temporaries too
    show_progress(False)  # the parent draws the one bar
    set_torch_threads(threads)
    _STATE = factory(*factory_args)
    set_torch_threads(threads)


def _worker_step(step: Step, path: Path, episode: Episode, payload: Any) -> float:
    start = time.monotonic()
    step(_STATE, path, episode, payload)
    return time.monotonic() - start


def run_staged(items: Sequence[tuple[Path, Episode, Any]], step: Step, desc: str, *, workers: int = 1,
               state: Any = None, factory: Callable[..., Any] | None = None, factory_args: tuple = (),
               executor: str = "local", address: str | None = None,
               read: Callable[[Path, Episode], Any] | None = None) -> list[Any] | None:
    """Run ``step`` on every ``(part path, episode, payload)`` whose part does not exist yet.

    One process (``workers=1``) uses ``state``; more spawn ``workers`` processes whose state each
    ``factory(*factory_args)`` makes (module-level functions and picklable arguments). Each episode
    is released once done. ``executor="ray"`` runs the episodes as tasks on ``workers`` Ray actors
    that share ``state``, on the cluster at ``address`` (default a local one). An error stops the job after the episodes in progress finish (their
    parts are kept, as every finished one is) and is raised here.

    ``read(part, episode)`` loads a part: given, a part left by an earlier run that it cannot load is
    redone (with a warning) and the loaded parts are returned in the order of ``items``.
    """
    kept: dict[Path, Any] = {}
    for path, ep, _ in items if read is not None else ():
        if path.exists():
            try:
                kept[path] = read(path, ep)
            except Exception as exc:  # noqa: BLE001 - any damage: the part is redone, never used
                log.warning("staged part %s of episode %r cannot be read back (%s); doing that episode again",
                            path, ep.name, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
                path.unlink(missing_ok=True)
    todo = [item for item in items if not item[0].exists()]
    done_frames = sum(int(ep.num_frames) for path, ep, _ in items if path.exists())
    total = sum(int(ep.num_frames) for _, ep, _ in items)
    with EpisodeBar(desc, len(items), total, done=len(items) - len(todo), done_frames=done_frames) as bar:
        _execute(todo, step, bar, workers, state, factory, factory_args, executor, address)
    if read is None:
        return None
    return [kept[path] if path in kept else _read_new(read, path, ep) for path, ep, _ in items]


def _read_new(read: Callable[[Path, Episode], Any], path: Path, episode: Episode) -> Any:
    """A part this run wrote, loaded (it cannot be damaged but by the disk: an error then names it)."""
    try:
        return read(path, episode)
    except UsageError:
        raise
    except Exception as exc:  # noqa: BLE001 - one line naming the part
        raise UsageError(f"{path}: the part this run staged for episode {episode.name!r} cannot be read back "
                         f"({exc}); delete {path.parent} and run again") from exc


def _execute(todo: list[tuple[Path, Episode, Any]], step: Step, bar: EpisodeBar, workers: int, state: Any,
             factory: Callable[..., Any] | None, factory_args: tuple, executor: str, address: str | None) -> None:
    """Do ``todo``'s episodes here, in ``workers`` processes, or on Ray (see :func:`run_staged`)."""
    if executor == "ray" and todo:
        from rdd.batch.ray_executor import run_on_ray

        run_on_ray(todo, step, bar, workers=workers, state=state, address=address)
        return
    if workers == 1 or len(todo) <= 1:
        for path, ep, payload in todo:
            start = time.monotonic()
            step(state, path, ep, payload)
            ep.release()
            bar.advance(ep.name, int(ep.num_frames), time.monotonic() - start)
        return
    import multiprocessing

    threads = max(1, cores() // workers)
    with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=multiprocessing.get_context("spawn"),
                             initializer=_worker_init, initargs=(factory, factory_args, threads)) as pool:
        queue = iter(todo)
        running: dict[Any, Episode] = {}
        try:
            # Submit as workers free up, so only the episodes in progress are in flight.
            for path, ep, payload in queue:
                running[pool.submit(_worker_step, step, path, ep, payload)] = ep
                if len(running) >= 2 * workers:
                    break
            while running:
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in finished:
                    ep = running.pop(fut)
                    seconds = fut.result()
                    bar.advance(ep.name, int(ep.num_frames), seconds)
                    nxt = next(queue, None)
                    if nxt is not None:
                        running[pool.submit(_worker_step, step, *nxt)] = nxt[1]
        except BaseException:
            for fut in running:
                fut.cancel()
            raise
