"""``--executor ray``: the per-episode work of ``rdd.batch.staging`` run as tasks on a Ray cluster.

The parent builds the command's components once (database, encoder, labeler) and puts them in
Ray's object store once; ``--workers N`` actors each take them from there and run the same step
function as a local run on one episode per task. Each task returns its part's bytes and the parent
writes the part beside the output, so parts, resume and the assembled output are those of a local
run; only the dataset (``--data``) must be readable at the same path on every node.

Without ``--ray-address`` a local cluster is started for the job (``--workers`` CPUs, a bounded
object store, no dashboard) and stopped after it; ``--ray-address auto`` joins the cluster this
node belongs to (``ray start``), ``ray://HEAD:10001`` a remote one. A Ray session the process has
already started (a test's, a notebook's) is used as it is.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rdd.atomic import write_bytes_atomic
from rdd.data.episode import Episode
from rdd.errors import UsageError
from rdd.progress import EpisodeBar

INSTALL = "make install-cluster (pip install -c constraints.txt -e '.[cluster]')"
# The local cluster's shared-memory object store: Ray's default (30% of memory, 7 GiB here) would
# take a third of a 24 GiB machine others share; the components are put once and episodes are
# never in it (each task reads its own), so 1 GiB holds a large database, and Ray spills to disk
# past it rather than fail.
OBJECT_STORE_BYTES = 1 << 30


def import_ray():
    """The ``ray`` module, or a one-line error with the install line."""
    try:
        import ray
    except ImportError as exc:
        raise UsageError(f"--executor ray needs Ray: {INSTALL}") from exc
    return ray


def _init(ray, workers: int, address: str | None) -> bool:
    """Connect to (``address``) or start a cluster; True when this call started the session."""
    if ray.is_initialized():
        return False
    options: dict[str, Any] = {"address": address, "log_to_driver": False, "configure_logging": False}
    if address is None:  # a cluster of our own: as many CPUs as workers, memory bounded
        options.update(num_cpus=workers, object_store_memory=OBJECT_STORE_BYTES, include_dashboard=False)
    try:
        ray.init(**options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise UsageError(f"--ray-address {address}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") \
            from exc
    return True


class _Worker:
    """One actor: the components, taken once from the object store, and the step run on each episode."""

    def __init__(self, step: Callable, state: Any):
        self.step, self.state = step, state
        self.scratch = Path(tempfile.mkdtemp(prefix="rdd-ray-"))

    def run(self, name: str, episode: Episode, payload: Any) -> tuple[bytes, float]:
        """Do one episode; its part's bytes and the seconds it took."""
        start = time.monotonic()
        path = self.scratch / name
        self.step(self.state, path, episode, payload)
        try:
            return path.read_bytes(), time.monotonic() - start
        finally:
            path.unlink(missing_ok=True)


def run_on_ray(todo: Sequence[tuple[Path, Episode, Any]], step: Callable, bar: EpisodeBar, *, workers: int,
               state: Any, address: str | None) -> None:
    """Run ``step`` on each ``(part path, episode, payload)`` of ``todo`` in ``workers`` Ray actors,
    writing each part here as its task returns; an error stops the job (finished parts are kept)."""
    ray = import_ray()
    started = _init(ray, workers, address)
    try:
        state_ref = ray.put(state)  # the database and encoder sent once; each actor reads them
        actor = ray.remote(num_cpus=1)(_Worker)
        actors = [actor.remote(step, state_ref) for _ in range(min(workers, len(todo)))]
        queue = iter(todo)
        running: dict[Any, tuple[Any, Path, Episode]] = {}

        def submit(worker) -> None:
            item = next(queue, None)
            if item is not None:
                path, ep, payload = item
                running[worker.run.remote(path.name, ep, payload)] = (worker, path, ep)

        # Two episodes per actor in flight: one running, the next already sent.
        for worker in actors * 2:
            submit(worker)
        try:
            while running:
                finished, _ = ray.wait(list(running), num_returns=1)
                worker, path, ep = running.pop(finished[0])
                try:
                    data, seconds = ray.get(finished[0])
                except ray.exceptions.RayTaskError as exc:
                    raise (exc.cause if isinstance(exc.cause, Exception) else exc) from None
                write_bytes_atomic(path, data)
                bar.advance(ep.name, int(ep.num_frames), seconds)
                submit(worker)
        finally:  # killing an actor drops its queued tasks too
            for worker in actors:
                ray.kill(worker)
    finally:
        if started:
            ray.shutdown()

