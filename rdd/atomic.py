"""The project's one way to write a file or a folder: all of it, or nothing.

Every writer (CLI outputs, databases, caches, stage outputs, checkpoints, plots, tables) goes
through :func:`atomic_file`, :func:`atomic_path` (for writers that need a file name) or
:func:`atomic_dir`: the data is written to a uniquely named
temporary sibling in the target folder, flushed to disk (``fsync``), and renamed into place, so a
crash or Ctrl-C leaves either the old file or the new one, never half of one, and two writers never
share a temporary name. Files get the permissions an ordinary ``open()`` would give them under the
process umask (``tempfile`` alone would leave them 0600). A failure names the target, never the
hidden temporary (the user knows only the target), also when the disk is full (a write's own error
names no file), and :func:`check_writable` tells before any work whether a target can be written at
all. A cache file that a C library writes or maps by name gets its sha256 beside it
(:func:`write_sha256`), and :func:`read_verified` gives its bytes only when they match. A process killed outright (SIGKILL, power loss) cannot remove its temporaries: whoever owns the
target next finds them with :func:`leftovers` and removes them.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

__all__ = [
    "TargetExistsError",
    "atomic_dir",
    "atomic_file",
    "atomic_path",
    "check_writable",
    "leftovers",
    "read_verified",
    "remove_temporaries",
    "write_sha256",
    "write_bytes_atomic",
    "write_json_atomic",
    "write_text_atomic",
]


class TargetExistsError(FileExistsError):
    """The target exists and the caller did not ask to replace it."""


# Errors that mean the filesystem has no room (a quota counts): the write's own error names no file.
FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
# mkstemp/mkdtemp's random part: 8 characters of this alphabet.
_RANDOM = "[a-z0-9_]{8}"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # some filesystems cannot open or fsync a folder
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _check_target(path: Path, overwrite: bool) -> None:
    if not overwrite and (path.exists() or path.is_symlink()):
        raise TargetExistsError(f"{path} already exists (refusing to replace it)")


def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def _existing_folder(path: Path) -> Path:
    """The nearest folder above ``path`` that exists (where its missing parents will be created)."""
    folder = Path(os.path.abspath(path)).parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def _temp_prefix(path: Path, stem: str, tail: str) -> str:
    """``.<stem>.`` of ``path``'s temporary siblings (``.<stem>.XXXXXXXX<tail>``), the stem shortened
    so that a target whose own name fits the filesystem has temporaries whose names fit too."""
    room = _name_max(_existing_folder(path)) - len(os.fsencode(tail)) - 10  # two dots, mkstemp's 8
    while stem and len(os.fsencode(stem)) > room:
        stem = stem[:-1]
    return f".{stem}."


@contextlib.contextmanager
def _errors_name(path: Path, prefix: str) -> Iterator[None]:
    """Re-raise an OSError about a temporary sibling of ``path`` (prefix ``prefix``) as one about ``path``."""
    try:
        yield
    except TargetExistsError:
        raise
    except OSError as exc:
        name = _target_of(exc.filename, path, prefix) or _target_of(exc.filename2, path, prefix)
        code = exc.errno
        if code is None and "No space left on device" in str(exc):
            code = errno.ENOSPC  # C libraries (Arrow) report a full disk in words
        if name is None and code in FULL_ERRNOS:
            # The file without room is the one written here: a write()'s error names no file, a
            # copy's names its source first.
            name = str(path)
        if name is None or code is None:
            raise
        raise OSError(code, exc.strerror or os.strerror(code), name) from exc


def _target_of(filename: Any, path: Path, prefix: str) -> str | None:
    """The target file that the temporary ``filename`` stands for (a file inside a temporary folder
    maps to the same file inside ``path``), or None when ``filename`` is not a temporary of ``path``."""
    if filename is None:
        return None
    name = Path(os.path.abspath(os.fsdecode(filename)))
    parent = Path(os.path.abspath(path.parent))
    for here in (name, *name.parents):
        if here.parent == parent and here.name.startswith(prefix) and here.name != path.name:
            return str(path / name.relative_to(here)) if here != name else str(path)
    return None


def leftovers(path: str | os.PathLike) -> list[Path]:
    """The temporaries of ``path`` beside it (of :func:`atomic_path`, :func:`atomic_dir`, and the old
    folder that an overwrite moves aside) that a killed writer left; only the owner of ``path`` may
    remove them (a live writer's temporary has the same form)."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    file_prefix = _temp_prefix(path, path.stem, f".tmp{path.suffix}")
    dir_prefix = _temp_prefix(path, path.name, ".tmp")
    forms = re.compile(f"{re.escape(file_prefix)}{_RANDOM}{re.escape('.tmp' + path.suffix)}|"
                       f"{re.escape(dir_prefix)}{_RANDOM}\\.(tmp|old)")
    return sorted(p for p in path.parent.iterdir() if forms.fullmatch(p.name))


def remove_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove every temporary of this module anywhere inside ``folder`` (a staging folder kept across
    runs, which a killed run may have left them in); returns what was removed. Only for a folder
    that one process owns: a live writer's temporary has the same form."""
    form = re.compile(f"\\..*\\.{_RANDOM}\\.(tmp(\\.[^.]+)?|old)")
    removed = []
    for root, dirs, files in os.walk(folder):
        for name in [*files, *dirs]:
            if form.fullmatch(name):
                target = Path(root) / name
                if target.is_dir() and not target.is_symlink():
                    shutil.rmtree(target, ignore_errors=True)
                else:
                    target.unlink(missing_ok=True)
                removed.append(target)
        dirs[:] = [d for d in dirs if not form.fullmatch(d)]
    return removed


def check_writable(path: str | os.PathLike) -> None:
    """Raise an OSError naming ``path`` when it could not be written: a file stands where a folder
    must, a name is longer than its filesystem allows, or its nearest existing folder refuses a new
    file (tried, so a read-only filesystem or root's permissions are judged as a write would be)."""
    path = Path(os.path.abspath(path))
    folder = _existing_folder(path)
    if not folder.is_dir():
        raise OSError(errno.ENOTDIR, f"{folder} is a file, not a folder", str(path))
    name_max = _name_max(folder)
    for part in path.relative_to(folder).parts:
        if len(os.fsencode(part)) > name_max:
            raise OSError(errno.ENAMETOOLONG, f"the name {part[:24]}... is {len(os.fsencode(part))} bytes long; "
                          f"the filesystem of {folder} allows {name_max}", str(path))
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".rdd-write-check.")
    except OSError as exc:
        raise OSError(exc.errno or errno.EACCES, f"cannot create files in {folder} ({exc.strerror or exc})",
                      str(path)) from None
    os.close(fd)
    os.unlink(probe)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = True) -> Iterator[Path]:
    """Yield a fresh temporary file name beside ``path`` (same suffix) for writers that need a name
    (C libraries, figure savers); on success that file is fsynced and renamed to ``path``.

    With ``overwrite=False`` an existing ``path`` raises :class:`TargetExistsError` and is kept (the
    final step is a hard link then, so a concurrent writer that got there first still wins alone).
    """
    path = Path(path)
    suffix = f".tmp{path.suffix}"
    prefix = _temp_prefix(path, path.stem, suffix)
    with _errors_name(path, prefix):
        path.parent.mkdir(parents=True, exist_ok=True)
        _check_target(path, overwrite)
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=suffix)
        tmp = Path(tmp_name)
        try:
            os.fchmod(fd, 0o666 & ~_umask())
            os.close(fd)
            yield tmp
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            if overwrite:
                os.replace(tmp, path)
            else:
                try:
                    os.link(tmp, path)  # fails if path appeared meanwhile: no silent replacement
                except FileExistsError as exc:
                    raise TargetExistsError(f"{path} already exists (refusing to replace it)") from exc
            _fsync_dir(path.parent)
        finally:
            tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "wb", *, overwrite: bool = True) -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing; on success it is fsynced and renamed to ``path``.

    ``overwrite=False`` behaves as in :func:`atomic_path`.
    """
    if "w" not in mode:
        raise ValueError(f"atomic_file writes whole files: mode must contain 'w', got {mode!r}")
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, mode) as fh:
        yield fh


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_file(path, "wb", overwrite=overwrite) as fh:
        fh.write(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, *, overwrite: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"), overwrite=overwrite)


def write_json_atomic(
    path: str | os.PathLike,
    obj: Any,
    *,
    overwrite: bool = True,
    dumps: Callable[[Any], str] | None = None,
) -> Path:
    """Write ``obj`` as JSON (indented, or through ``dumps``) to ``path`` atomically; returns the path."""
    text = dumps(obj) if dumps is not None else json.dumps(obj, indent=1) + "\n"
    return write_text_atomic(path, text, overwrite=overwrite)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; on success it is renamed to ``path``.

    The folder only appears under its final name once everything in it is written. With
    ``overwrite=False`` an existing ``path`` raises :class:`TargetExistsError` (before and after
    the work, so a concurrent writer that finished first is never replaced); with ``True`` the old
    folder is moved aside and removed only after the new one is in place.
    """
    path = Path(path)
    prefix = _temp_prefix(path, path.name, ".tmp")  # ".old" for the replaced folder: as long
    with _errors_name(path, prefix):
        path.parent.mkdir(parents=True, exist_ok=True)
        _check_target(path, overwrite)
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=prefix, suffix=".tmp"))
        try:
            os.chmod(tmp, 0o777 & ~_umask())
            yield tmp
            for root, _dirs, files in os.walk(tmp):
                for name in files:
                    with contextlib.suppress(OSError):
                        fd = os.open(os.path.join(root, name), os.O_RDONLY)
                        try:
                            os.fsync(fd)
                        finally:
                            os.close(fd)
            old: Path | None = None
            if path.exists() or path.is_symlink():
                if not overwrite:
                    raise TargetExistsError(f"{path} already exists (refusing to replace it)")
                old = Path(tempfile.mkdtemp(dir=path.parent, prefix=prefix, suffix=".old"))
                os.replace(path, old / "previous")
            try:
                os.rename(tmp, path)  # fails if a concurrent writer created path meanwhile
            except OSError as exc:
                if old is not None:
                    os.replace(old / "previous", path)
                raise TargetExistsError(f"{path} already exists (another writer finished first)") from exc
            finally:
                if old is not None:
                    shutil.rmtree(old, ignore_errors=True)
            _fsync_dir(path.parent)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)


def _sha256_path(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def write_sha256(path: str | os.PathLike) -> Path:
    """Write the sha256 of ``path``'s bytes beside it (``<name>.sha256``, atomically); returns that file."""
    path = Path(path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return write_text_atomic(_sha256_path(path), digest + "\n")


def read_verified(path: str | os.PathLike) -> bytes:
    """The bytes of ``path``, read once, when they match the sha256 beside it (:func:`write_sha256`);
    a ValueError saying what is wrong otherwise (the caller names the file and what it does next)."""
    path = Path(path)
    data = path.read_bytes()
    try:
        stored = _sha256_path(path).read_text().strip()
    except OSError as exc:
        raise ValueError(f"its checksum file {_sha256_path(path)} cannot be read: {exc.strerror}") from exc
    if hashlib.sha256(data).hexdigest() != stored:
        raise ValueError("its sha256 does not match the one written with it (damaged)")
    return data
