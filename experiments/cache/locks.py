"""A lock file that works across processes and hosts on one shared filesystem (NFS, Lustre, GPFS).

``flock``/``fcntl`` locks are not reliable on every shared filesystem, so the lock is
:class:`filelock.SoftFileLease`: a marker file created with ``O_CREAT | O_EXCL`` that names its
owner (host, pid, process start, a random token), refreshed by a heartbeat thread while it is held.

A waiter takes a lock over when its owner is gone:
- on the same host, at once, when the owner's process no longer exists (a killed job);
- on any host, when the marker has not changed for ``stale_after_s`` seconds of the waiter's own
  monotonic clock (a dead node), so clock skew between hosts does not matter. A job that is paused
  (SIGSTOP, a suspended Slurm job) for longer than that loses its lock.
filelock takes a marker over by swapping names atomically (``renameat2(RENAME_EXCHANGE)``), which
NFS and SMB refuse; there it never would, so a waiter whose lock file has not moved for twice
``stale_after_s`` removes it (:meth:`FileLock.acquire`).

Mutual exclusion here only saves work (a stage built once instead of twice). Correctness never
depends on it: finished outputs appear by an atomic rename that refuses to replace an existing
entry, so even two holders (a lock wrongly judged stale) cannot leave a mixed or partial result.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from filelock import SoftFileLease, Timeout

log = logging.getLogger(__name__)

HEARTBEAT_S = 10.0
STALE_AFTER_S = 120.0


def _marker_id(path: Path) -> tuple[int, int] | None:
    """Inode and mtime of the lock file (a refresh or a new owner changes them), None when absent."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_mtime_ns


class FileLock:
    """An exclusive lock on ``path`` shared by processes on any host that sees the same filesystem.

    Use as a context manager. ``heartbeat_s``: how often the holder touches the file;
    ``stale_after_s``: how long a waiter watches an unmoving lock before taking it over (keep it
    several heartbeats long; every job sharing the lock must use the same value);
    ``poll_s``: the pause between a waiter's looks.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        heartbeat_s: float = HEARTBEAT_S,
        stale_after_s: float = STALE_AFTER_S,
        poll_s: float = 0.5,
        label: str | None = None,
    ) -> None:
        if stale_after_s <= heartbeat_s:
            raise ValueError(f"stale_after_s ({stale_after_s}) must exceed heartbeat_s ({heartbeat_s})")
        self.path = Path(path)
        self.stale_after_s = stale_after_s
        self.label = label or str(self.path)
        self._lease = SoftFileLease(self.path, lease_duration=float(stale_after_s),
                                    heartbeat_interval=float(heartbeat_s), poll_interval=float(poll_s),
                                    on_compromise=self._lost)

    def _lost(self, compromise) -> None:
        log.warning("lost %s (%s): another job judged it stale and took it over", self.label,
                    compromise.reason)

    def try_acquire(self) -> bool:
        """Take the lock if it is free (or its owner is gone); True when this object now holds it."""
        try:
            self._lease.acquire(blocking=False)
        except Timeout:
            return False
        return True

    def acquire(self) -> None:
        """Wait until the lock is free (or its owner is gone) and take it."""
        if self.try_acquire():
            return
        owner = self._lease.owner
        log.info("waiting for %s (held by %s pid %s)", self.label, owner and owner.hostname,
                 owner and owner.pid)
        while True:
            seen = _marker_id(self.path)
            try:
                self._lease.acquire(timeout=2 * self.stale_after_s)
                return
            except Timeout:
                # Still there and unmoved for twice the stale limit: filelock could not swap it out
                # (a filesystem without the exchange), so remove it and take the free name.
                if seen is not None and _marker_id(self.path) == seen:
                    log.warning("took over %s: its lock file has not moved for %g s", self.label,
                                2 * self.stale_after_s)
                    self._lease.force_break()

    def release(self) -> None:
        """Stop the heartbeat and remove the lock file if it is still ours."""
        self._lease.release()

    def __enter__(self) -> FileLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
