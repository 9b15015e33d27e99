"""On-disk stage cache: each pipeline stage's output lives in a directory keyed by what made it.

A stage's key is the SHA-256 of a canonical JSON "spec": the config entries that affect the stage,
the keys of the stages it consumes, and a fingerprint of the source that makes it, derived from its
imports (``experiments.cache.code_keys``), so changing anything upstream, config or code, changes every key below it.
Outputs are built in a temporary folder and renamed into place (:func:`rdd.atomic.atomic_dir`), so a
job killed mid-stage leaves no entry a later job could take for a result. A per-key lock file
(:class:`experiments.cache.locks.FileLock`: owner host/pid, heartbeat, stale-lock takeover; no ``flock``, so
it holds on NFS-like shared filesystems too) makes concurrent jobs, local or on a cluster, that need
the same stage build it once: the others wait and take the finished entry. A cache folder that
cannot be written does not stop a run: :meth:`StageCache.for_run` then builds the run's stages in a
temporary folder, removed when the run ends, and says so in one warning line.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.cache.code_keys import StageCodes
from experiments.cache.locks import HEARTBEAT_S, STALE_AFTER_S, FileLock
from rdd.atomic import (
    TargetExistsError,
    atomic_dir,
    check_writable,
    leftovers,
    remove_temporaries,
    write_json_atomic,
)

__all__ = ["StageCache", "StageTiming", "canonical", "read_json", "spec_key"]

log = logging.getLogger(__name__)

# Bump when a stage's on-disk layout or meaning changes, so old entries are not reused.
CACHE_FORMAT = 1
SPEC_FILE = "spec.json"


def canonical(obj: Any) -> Any:
    """A JSON-ready copy of ``obj`` with stable ordering (OmegaConf nodes, paths, tuples, enums)."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(obj, DictConfig | ListConfig):
            obj = OmegaConf.to_container(obj, resolve=True, enum_to_str=True)
    except ImportError:  # pragma: no cover - omegaconf is a harness dependency
        pass
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, list | tuple):
        return [canonical(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "value") and hasattr(obj, "name") and type(obj).__module__ != "builtins":
        return canonical(obj.value)  # Enum
    if isinstance(obj, float | int | str | bool) or obj is None:
        return obj
    raise TypeError(f"cannot put {type(obj).__name__} into a stage cache key: {obj!r}")


def spec_key(spec: dict[str, Any]) -> str:
    """SHA-256 (first 16 hex digits) of the canonical JSON of ``spec``."""
    text = json.dumps(canonical({"format": CACHE_FORMAT, **spec}), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class StageTiming:
    """Wall time of one stage and whether it came from the cache."""

    seconds: float
    cached: bool
    built: int = 0  # calls that built an entry
    reused: int = 0  # calls that found it in the cache


@dataclass
class StageCache:
    """A root directory of cached stages, ``<root>/<stage>/<key>/``, shared safely by concurrent jobs.

    ``heartbeat_s`` and ``stale_after_s`` tune the per-key locks (see :class:`FileLock`): a lock
    whose file has not been touched for ``stale_after_s`` seconds is taken over (at once when its
    owner was a process on this host that no longer exists).
    """

    root: Path
    timings: dict[str, StageTiming] = field(default_factory=dict)
    heartbeat_s: float = HEARTBEAT_S
    stale_after_s: float = STALE_AFTER_S
    temporary: bool = False  # a folder of this run only (the shared one could not be written)
    codes: StageCodes = field(default_factory=StageCodes)  # each stage's code fingerprint, computed once

    def __post_init__(self) -> None:
        self.root = Path(self.root)

    @classmethod
    def for_run(cls, root: str | Path) -> StageCache:
        """The cache at ``root``, or, when that folder cannot be written (read-only, no permission),
        a temporary one for this run: nothing is reused or kept, and one warning line says so."""
        try:
            check_writable(Path(root) / SPEC_FILE)  # what a lock or an entry would need: a new file there
        except OSError as exc:
            tmp = Path(tempfile.mkdtemp(prefix="rdd-stage-cache-"))
            log.warning("stage cache %s cannot be written (%s): this run builds its stages in %s, removed when "
                        "it ends, so nothing is reused or kept", root, exc.strerror, tmp)
            return cls(tmp, temporary=True)
        return cls(Path(root))

    def close(self) -> None:
        """Remove a temporary cache (:meth:`for_run`); a shared one is kept."""
        if self.temporary:
            shutil.rmtree(self.root, ignore_errors=True)

    def path(self, stage: str, key: str) -> Path:
        """Directory of a finished stage entry."""
        return self.root / stage / key

    def progress_path(self, stage: str, key: str) -> Path:
        """Where a resumable build of (stage, key) keeps what it saved so far (kept across kills)."""
        return self.root / stage / f".{key}.progress"

    @contextlib.contextmanager
    def lock(self, stage: str, key: str, wait: bool = True) -> Iterator[bool]:
        """Exclusive lock on (stage, key) across processes and hosts sharing the cache folder.

        Yields True once held; with ``wait=False`` it does not wait and yields False (holding
        nothing) when another job holds it.
        """
        lock_dir = self.root / stage
        lock_dir.mkdir(parents=True, exist_ok=True)
        lock = FileLock(lock_dir / f".{key}.lock.json", heartbeat_s=self.heartbeat_s,
                        stale_after_s=self.stale_after_s, label=f"stage {stage}/{key}")
        if wait:
            lock.acquire()
        elif not lock.try_acquire():
            yield False
            return
        try:
            yield True
        finally:
            lock.release()

    def get_or_build(
        self,
        stage: str,
        spec: dict[str, Any],
        build: Callable[[Path], None],
        timing_name: str | None = None,
        wait: bool = True,
        code: tuple[str, ...] = (),
        uses: Any = None,
        resumable: bool = False,
    ) -> tuple[Path, str] | None:
        """Directory holding ``stage``'s output for ``spec``, calling ``build(tmp_dir)`` on a miss.

        Returns ``(directory, key)``. The timing goes to ``self.timings[timing_name or stage]``
        (accumulated when a stage runs several times in one run, e.g. once per task).
        ``wait=False``: None at once when the entry is missing and another job is building it.
        ``code``: source files beyond what the stage's builders import (e.g. one task's modules) in
        its key; ``uses``: config nodes of components it runs that its spec does not hold (their
        ``_target_`` modules join its code key). ``resumable``: ``build(tmp_dir, progress_dir)``, where
        ``progress_dir`` (:meth:`progress_path`) outlives a killed build, so the same key built again
        goes on from what it saved there; it is removed once the entry is finished.
        """
        fingerprint = self.codes.key(stage, code, spec, uses)
        # Made canonical once: the key hashes it, and a built entry records it as its spec file.
        spec = canonical(spec if fingerprint is None else {**spec, "code": fingerprint})
        key = spec_key(spec)
        final = self.path(stage, key)
        start = time.perf_counter()
        cached = True
        if not (final / SPEC_FILE).is_file():
            with self.lock(stage, key, wait=wait) as held:
                if not held:
                    return None
                if not (final / SPEC_FILE).is_file():  # another job may have built it meanwhile
                    if resumable:
                        progress = self.progress_path(stage, key)
                        if progress.is_dir():
                            remove_temporaries(progress)  # a save that a kill cut short
                        cached = self._build(final, spec, lambda tmp: build(tmp, progress))
                    else:
                        cached = self._build(final, spec, build)
        if resumable:  # finished: what a build saved on the way is no longer needed (nor after a kill just then)
            shutil.rmtree(self.progress_path(stage, key), ignore_errors=True)
        self._record(timing_name or stage, time.perf_counter() - start, cached)
        return final, key

    def _build(self, final: Path, spec: dict[str, Any], build: Callable[[Path], None]) -> bool:
        """Build ``final`` under its lock (``spec``: canonical); False when built here, True if another
        job's finished entry won."""
        _clear_leftovers(final)
        try:
            with atomic_dir(final) as tmp:
                build(tmp)
                # Written last: an entry is finished exactly when its spec file is there.
                write_json_atomic(tmp / SPEC_FILE, spec,
                                  dumps=lambda obj: json.dumps(obj, indent=1, sort_keys=True))
        except TargetExistsError:
            # Only when a lock was wrongly judged stale and two jobs built: the first rename wins.
            if not (final / SPEC_FILE).is_file():
                raise
            log.warning("%s was finished by another job meanwhile; using that entry", final)
            return True
        return False

    def _record(self, name: str, seconds: float, cached: bool) -> None:
        prev = self.timings.get(name) or StageTiming(0.0, True)
        self.timings[name] = StageTiming(prev.seconds + seconds, prev.cached and cached,
                                         prev.built + (not cached), prev.reused + bool(cached))
        log.debug("stage %s: %s in %.2f s", name, "reused" if cached else "built", seconds)

    @contextlib.contextmanager
    def timed(self, name: str) -> Iterator[dict[str, bool]]:
        """Record the wall time of a step under ``name``; set ``flag["cached"]`` if it did no work."""
        flag = {"cached": False}
        start = time.perf_counter()
        try:
            yield flag
        finally:
            self._record(name, time.perf_counter() - start, flag["cached"])


def read_json(path: Path) -> Any:
    """Load JSON, naming the file when it is missing or corrupt."""
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"missing file {path}") from exc
    except json.JSONDecodeError as exc:
        raise ValueError(f"corrupt JSON in {path}: {exc}") from exc


def _clear_leftovers(final: Path) -> None:
    """Remove what killed builds of ``final`` left: temporary folders, an entry without its spec file.

    Called with ``final``'s lock held, so no live job is writing any of them.
    """
    parent = final.parent
    if not parent.is_dir():
        return
    # atomic_dir's temporaries of the entry, and the older ".tmp-<key>-..." folders.
    for p in [*leftovers(final), *parent.glob(f".tmp-{final.name}-*")]:
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
    if final.exists() and not (final / SPEC_FILE).is_file():
        shutil.rmtree(final)
