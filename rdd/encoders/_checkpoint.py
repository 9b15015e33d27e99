"""Loading official checkpoints from local files only, with messages that say where the file goes."""

from __future__ import annotations

import argparse
import os
import pickle
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

from rdd.errors import InputError

WEIGHTS_ENV = "RDD_WEIGHTS_DIR"
LFS_POINTER = b"version https://git-lfs.github.com/spec/"


class MissingCheckpointError(FileNotFoundError):
    """An encoder's weights file is not on this machine (nothing is ever downloaded)."""


def resolve_checkpoint(name: str, checkpoint: str | os.PathLike | None, filename: str, source: str) -> Path:
    """The checkpoint path: ``checkpoint`` if given, else ``$RDD_WEIGHTS_DIR/<name>/<filename>``.

    Raises MissingCheckpointError naming the expected file, where the official project publishes it
    and where to put it.
    """
    if checkpoint is not None:
        path = Path(checkpoint).expanduser()
        if path.is_file():
            return path
        raise MissingCheckpointError(
            f"encoder {name!r}: checkpoint file {str(path)!r} (option checkpoint) does not exist. "
            f"Expected the official file {filename!r}, published at {source}."
        )
    root = os.environ.get(WEIGHTS_ENV)
    if root:
        path = Path(root).expanduser() / name / filename
        if path.is_file():
            return path
        where = f"{path} (from ${WEIGHTS_ENV})"
    else:
        where = f"${WEIGHTS_ENV}/{name}/{filename} (${WEIGHTS_ENV} is not set)"
    raise MissingCheckpointError(
        f"encoder {name!r} needs its official weights file {filename!r}, which is not on this machine "
        f"and is never downloaded at run time. Get it from {source} and either put it at {where} "
        f"or pass its path as the option checkpoint=PATH (CLI: --encoder-option checkpoint=/path/{filename}; "
        f"Hydra: encoder.checkpoint=/path/{filename})."
    )


def _is_torchscript(path: Path) -> bool:
    """True for a TorchScript archive (e.g. OpenAI's CLIP ``RN50.pt``), which holds code, not a pickle."""
    if not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as zf:
        return any(n.endswith("constants.pkl") or "/code/" in n for n in zf.namelist())


def _first_sentence(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {re.split(r'(?<=[.!?]) ', text, maxsplit=1)[0]}" if text else type(exc).__name__


def unreadable_reason(path: Path, exc: BaseException) -> str:
    """What is wrong with checkpoint ``path`` (``exc``: torch.load's error) in one clause, never torch's
    advice to drop weights_only."""
    with open(path, "rb") as fh:
        head = fh.read(len(LFS_POINTER))
    if not head:
        return "is empty (an interrupted download?)"
    if head == LFS_POINTER:
        return "is a Git LFS pointer, not the weights (fetch the real file: git lfs pull)"
    # torch wraps the weights-only unpickler's own error in paragraphs of advice; keep only that error.
    inner = exc.__context__ if isinstance(exc, pickle.UnpicklingError) and exc.__context__ else exc
    refused = re.search(r"GLOBAL ([\w.]+)", str(inner))
    if refused:
        return (f"holds pickled Python objects ({refused.group(1)}), which are refused because loading them "
                "could run code (a whole pickled model, not a file of weights)")
    return f"is not a readable checkpoint: truncated, corrupt or another kind of file ({_first_sentence(inner)})"


def load_state(path: Path, name: str, filename: str | None = None, source: str | None = None) -> dict[str, Any]:
    """The object stored in ``path``: safetensors, a TorchScript archive's state dict, or
    ``torch.load(weights_only=True)`` (which refuses arbitrary pickled code).

    A file that cannot be read is an InputError in one line naming the file, the encoder that wanted
    it, what is wrong with it and where the official ``filename`` comes from (``source``).
    """
    import torch

    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file

            return load_file(str(path), device="cpu")
        if _is_torchscript(path):
            return torch.jit.load(str(path), map_location="cpu").state_dict()
        # MAE-style training checkpoints (VC-1's lineage) store their argparse ``args`` beside the
        # weights; a Namespace only holds attributes, so it is the one extra class let through.
        with torch.serialization.safe_globals([argparse.Namespace]), warnings.catch_warnings():
            # Its note on pickle protocols only ever precedes the error reported below.
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            return torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - re-raised with the file and encoder named
        wanted = f"; expected the official file {filename!r}" if filename else ""
        wanted += f" from {source}" if source else ""
        raise InputError(f"encoder {name!r}: checkpoint {str(path)!r} {unreadable_reason(path, exc)}{wanted}") from exc


def load_strict(module, state: dict[str, Any], name: str, path: Path | str) -> None:
    """Load ``state`` into ``module`` requiring an exact key match; the error names file and keys."""
    result = module.load_state_dict(state, strict=False)
    if result.missing_keys or result.unexpected_keys:
        raise InputError(
            f"encoder {name!r}: checkpoint {str(path)!r} does not match the official layout: "
            f"{len(result.missing_keys)} missing keys {list(result.missing_keys)[:5]}, "
            f"{len(result.unexpected_keys)} unexpected keys {list(result.unexpected_keys)[:5]}"
        )


def take_prefix(
    state: Any, prefix: str, name: str, path: Path | str, ignore: tuple[str, ...] = ()
) -> dict[str, Any]:
    """Keys of ``state`` under ``prefix`` with the prefix removed; keys under ``ignore`` prefixes are
    dropped (parts the official encoder does not use); any other key is an error."""
    if not isinstance(state, dict):
        raise InputError(f"encoder {name!r}: checkpoint {str(path)!r} holds {type(state).__name__}, not a state dict")
    out, stray = {}, []
    for key, value in state.items():
        if key.startswith(prefix):
            out[key[len(prefix):]] = value
        elif not key.startswith(ignore):
            stray.append(key)
    if stray or not out:
        raise InputError(
            f"encoder {name!r}: checkpoint {str(path)!r} is not in the official layout: expected keys under "
            f"{prefix!r}" + (f" (and {list(ignore)})" if ignore else "")
            + (f"; found {len(out)} such keys and unexpected keys {stray[:5]}" if stray else "; found none")
        )
    return out


def take_entry(obj: Any, entry: str, name: str, path: Path | str) -> Any:
    """``obj[entry]`` (e.g. the ``'r3m'`` dict of R3M's ``model.pt``) or an error naming what was found."""
    if not isinstance(obj, dict) or entry not in obj:
        found = sorted(obj)[:8] if isinstance(obj, dict) else type(obj).__name__
        raise InputError(
            f"encoder {name!r}: checkpoint {str(path)!r} has no {entry!r} entry (found {found}); "
            f"is it the official file?"
        )
    return obj[entry]
