"""Work done episode by episode, staged beside the output, so a long run that stops resumes where it stopped.

A command over many episodes (``decompose``; ``build-db``'s embedding) writes each finished
episode's result at once, atomically, into a hidden folder beside its output (``.<out>.parts/``),
under a name made of the episode and a hash of the command's settings that affect results. A rerun
of the same command, after a crash, a Ctrl-C or a ``kill -9``, does only the episodes missing there
(a rerun with other settings finds none of its own); the output is assembled from the parts in
episode order, so it is the same bytes as an uninterrupted run's, and the folder is removed once
the output is written. Episodes are read, worked on and released one at a time.

``--workers N`` runs the episodes in N processes on this machine (spawned: each builds its own
components from the command's arguments, with cores // N torch threads), each taking the next
episode as it finishes one; one bar counts the whole job. ``--executor ray`` runs the same step
function as tasks on a Ray cluster instead (``rdd.batch.ray_executor``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rdd.data.episode import Episode
from rdd.progress import EpisodeBar, show_progress

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
               executor: str = "local", address: str | None = None) -> None:
    """Run ``step`` on every ``(part path, episode, payload)`` whose part does not exist yet.

    One process (``workers=1``) uses ``state``; more spawn ``workers`` processes whose state each
    ``factory(*factory_args)`` makes (module-level functions and picklable arguments). Each episode
    is released once done. ``executor="ray"`` runs the episodes as tasks on ``workers`` Ray actors
    that share ``state``, on the cluster at ``address`` (default a local one). An error stops the job after the episodes in progress finish (their
    parts are kept, as every finished one is) and is raised here.
    """
    todo = [item for item in items if not item[0].exists()]
    done_frames = sum(int(ep.num_frames) for path, ep, _ in items if path.exists())
    total = sum(int(ep.num_frames) for _, ep, _ in items)
    with EpisodeBar(desc, len(items), total, done=len(items) - len(todo), done_frames=done_frames) as bar:
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
