"""A lock file that works across processes and hosts on one shared filesystem (NFS, Lustre, GPFS).

``flock``/``fcntl`` locks are not reliable on every shared filesystem, so the lock is a plain file
created atomically (written beside the target and hard-linked into place, which fails if the name
exists: :func:`rdd.atomic.write_json_atomic` with ``overwrite=False``). It records its owner (host,
pid, a random token) and a heartbeat thread touches it while it is held.

A waiter takes a lock over when its owner is gone:
- on the same host, at once, when the owner's pid no longer exists (a killed job);
- on any host, when the lock file's mtime has not moved for ``stale_after_s`` seconds of the
  waiter's own clock (a dead node). Only the waiter's monotonic clock is used, so clock skew between
  hosts does not matter. A job that is paused (SIGSTOP, a suspended Slurm job) for longer than that
  loses its lock. Assumed: one host name per pid namespace (containers that share a host name and a
  cache folder but not their pids would take each other's locks over; only work is lost then).

Mutual exclusion here only saves work (a stage built once instead of twice). Correctness never
depends on it: finished outputs appear by an atomic rename that refuses to replace an existing
entry, so even two holders (a lock wrongly judged stale) cannot leave a mixed or partial result.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import secrets
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rdd.atomic import TargetExistsError, write_json_atomic

log = logging.getLogger(__name__)

HEARTBEAT_S = 10.0
STALE_AFTER_S = 120.0


def _read_owner(path: Path) -> dict[str, Any] | None:
    """The owner record of a lock file, or None when it is gone (or unreadable: a foreign file)."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {}


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _mtime(path: Path) -> float | None:
    try:
        return path.stat().st_mtime_ns / 1e9
    except FileNotFoundError:
        return None


@dataclass
class _Watch:
    """What a waiter has seen of the current lock file: owner token, mtime, and since when."""

    token: str | None
    mtime: float | None
    since: float


class FileLock:
    """An exclusive lock on ``path`` shared by processes on any host that sees the same filesystem.

    Use as a context manager. ``heartbeat_s``: how often the holder touches the file;
    ``stale_after_s``: how long a waiter watches an unmoving lock before taking it over (keep it
    several heartbeats long); ``poll_s``: the longest pause between a waiter's looks.
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
        self.heartbeat_s = heartbeat_s
        self.stale_after_s = stale_after_s
        self.poll_s = poll_s
        self.label = label or str(self.path)
        self.token: str | None = None
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    # --- holding ---------------------------------------------------------------------------------
    def try_acquire(self) -> bool:
        """Take the lock if it is free; True when this object now holds it."""
        token = secrets.token_hex(8)
        owner = {"host": socket.gethostname(), "pid": os.getpid(), "token": token,
                 "started": time.time(), "label": self.label}
        try:
            write_json_atomic(self.path, owner, overwrite=False)
        except TargetExistsError:
            # Over NFS a retransmitted link() can report EEXIST for the link it just made itself.
            if (_read_owner(self.path) or {}).get("token") != token:
                return False
        self.token = token
        self._stop.clear()
        self._beat = threading.Thread(target=self._heartbeat, name=f"lock-heartbeat {self.label}",
                                      daemon=True)
        self._beat.start()
        return True

    def acquire(self) -> None:
        """Wait until the lock is free (or its owner is gone) and take it."""
        watch = _Watch(None, None, time.monotonic())
        pause = min(0.05, self.poll_s)
        told = False
        while not self.try_acquire():
            owner = _read_owner(self.path)
            if owner is None:
                continue  # released between our two looks: try again at once
            if not told:
                log.info("waiting for %s (held by %s pid %s)", self.label, owner.get("host"),
                         owner.get("pid"))
                told = True
            if self._owner_gone(owner, watch):
                self._take_over(owner)
                continue
            time.sleep(pause)
            pause = min(pause * 2, self.poll_s)

    def release(self) -> None:
        """Stop the heartbeat and remove the lock file if it is still ours."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
            self._beat = None
        if self.token is not None and (_read_owner(self.path) or {}).get("token") == self.token:
            self.path.unlink(missing_ok=True)
        self.token = None

    def __enter__(self) -> FileLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _heartbeat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            if (_read_owner(self.path) or {}).get("token") != self.token:
                log.warning("lost %s: another job judged it stale and took it over", self.label)
                return
            with contextlib.suppress(FileNotFoundError):
                os.utime(self.path)

    # --- waiting ---------------------------------------------------------------------------------
    def _owner_gone(self, owner: dict[str, Any], watch: _Watch) -> bool:
        """True when the owner is known dead, or its lock has not moved for ``stale_after_s``."""
        if owner.get("host") == socket.gethostname() and isinstance(owner.get("pid"), int) \
                and not _pid_alive(owner["pid"]):
            return True
        now = time.monotonic()
        mtime = _mtime(self.path)
        if owner.get("token") != watch.token or mtime != watch.mtime:
            watch.token, watch.mtime, watch.since = owner.get("token"), mtime, now
            return False
        return now - watch.since >= self.stale_after_s

    def _take_over(self, owner: dict[str, Any]) -> None:
        """Remove the stale lock file ``owner`` wrote, and nothing newer that replaced it meanwhile."""
        grave = self.path.with_name(f"{self.path.name}.stale-{secrets.token_hex(4)}")
        try:
            os.rename(self.path, grave)
        except FileNotFoundError:
            return  # another waiter removed it first
        moved = _read_owner(grave) or {}
        if moved.get("token") != owner.get("token"):
            # Another waiter already replaced the stale lock and we moved its fresh one: put it back
            # (unless a third took the free name, in which case both build and the rename decides).
            with contextlib.suppress(FileExistsError):
                os.link(grave, self.path)
        else:
            log.warning("took over %s from %s pid %s (owner gone)", self.label, owner.get("host"),
                        owner.get("pid"))
        grave.unlink(missing_ok=True)
