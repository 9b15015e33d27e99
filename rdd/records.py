"""The ``decompose`` output: one record per episode (segments, keyframes, scores, instructions and
where each came from, novelty, confidence), filling in missing instructions, and reading such files.

A reviewed file (``python -m rdd review``) is the same format, so it reads back with
:func:`read_segments_file` wherever a decompose output does.
"""

from __future__ import annotations

import json
import string
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.data.episode import Episode
from rdd.errors import UsageError
from rdd.labelers.base import label_all
from rdd.segments import validate_segments

OUTPUT_VERSION = 1  # of the decompose output (its config's "version")
FALLBACK_FIELDS = ("task", "episode", "index", "count", "start", "end")


def check_template(template: str) -> None:
    """Refuse a ``--fallback-instruction`` field that is not a plain name of FALLBACK_FIELDS: attribute
    or index access (``{task.__class__}``), conversions (``!r``) and nested fields would let a template
    write Python internals into a dataset."""
    fields = ", ".join("{" + f + "}" for f in FALLBACK_FIELDS)
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise UsageError(f"--fallback-instruction {template!r}: {exc}; fields: {fields}") from exc
    for _text, name, spec, conversion in parsed:
        if name is None:
            continue
        if name not in FALLBACK_FIELDS or conversion or "{" in (spec or ""):
            shown = "{" + name + (f"!{conversion}" if conversion else "") + (f":{spec}" if spec else "") + "}"
            raise UsageError(f"--fallback-instruction {template!r}: field {shown} is not allowed; fields are the plain "
                           f"names {fields} (no attribute or index access, no !r/!s/!a, no nested fields)")


def fallback_instruction(template: str, episode: Episode, index: int, count: int, segment) -> str:
    """``--fallback-instruction`` filled in for one segment (fields: FALLBACK_FIELDS)."""
    check_template(template)
    try:
        return template.format(task=episode.goal or episode.task, episode=episode.name, index=index + 1,
                               count=count, start=int(segment[0]), end=int(segment[1]))
    except (KeyError, IndexError, ValueError) as exc:
        raise UsageError(f"--fallback-instruction {template!r}: {exc!r}; fields: "
                       + ", ".join("{" + f + "}" for f in FALLBACK_FIELDS)) from exc


def episode_record(episode: Episode, result) -> dict[str, Any]:
    """One episode's entry in the ``decompose`` output."""
    segments = validate_segments(result.segments, episode.num_frames)
    instructions = getattr(result, "instructions", None)
    if instructions is None and result.neighbours is not None:
        instructions = [n.get("instruction") for n in result.neighbours]
    return {
        "episode": episode.name,
        "num_frames": episode.num_frames,
        "segments": [[s, e] for s, e in segments],
        "keyframes": [e - 1 for _, e in segments],
        "scores": None if result.scores is None else [float(x) for x in result.scores],
        "instructions": None if instructions is None else ["" if t is None else str(t) for t in instructions],
        "instruction_sources": None,
        "novelty": None if result.novelty is None else float(result.novelty),
        **confidence_fields(result),
    }


def confidence_fields(result) -> dict[str, Any]:
    """``confidence`` and ``neighbours`` (the matched entry: episode, segment, label) per segment, for
    a decomposer that gives them (rdd); none otherwise, so other outputs keep their bytes."""
    if result.confidence is None:
        return {}
    return {"confidence": [round(float(c), 4) for c in result.confidence],
            "neighbours": None if result.neighbours is None else [
                {"entry": n["entry"], "episode": n["episode"], "segment": [n["start"], n["end"]],
                 "label": n["instruction"] or None, "distance": round(float(n["distance"]), 6)}
                for n in result.neighbours]}


def fill_instructions(record: dict[str, Any], episode: Episode, labeler=None, fallback: str | None = None) -> None:
    """Give every segment without an instruction the labeler's, else the fallback's (recording which)."""
    if labeler is None and fallback is None:
        return
    segments = [tuple(s) for s in record["segments"]]
    given = record["instructions"] or [""] * len(segments)
    sources = ["decomposer" if t and t.strip() else None for t in given]
    texts = list(given)
    missing = [j for j, src in enumerate(sources) if src is None]
    if labeler is not None and missing:
        for j, text in zip(missing, label_all(labeler, episode, [segments[j] for j in missing]), strict=True):
            if text and text.strip():
                texts[j], sources[j] = text, "labeler"
    if fallback is not None:
        for j, src in enumerate(sources):
            if src is None:
                texts[j] = fallback_instruction(fallback, episode, j, len(segments), segments[j])
                sources[j] = "fallback"
    record["instructions"], record["instruction_sources"] = texts, sources


def lerobot_subtasks(episodes: Sequence[Episode], records: Sequence[dict[str, Any]], decomposer: str,
                     ) -> dict[int, tuple[list, list[str]]]:
    """Episode index -> (segments, instructions) for the LeRobot writer; every segment needs an instruction."""
    out = {}
    for ep, rec in zip(episodes, records, strict=True):
        instr = rec["instructions"]
        empty = [j for j, t in enumerate(instr or [None] * len(rec["segments"])) if not t or not str(t).strip()]
        if empty:
            raise UsageError(
                f"--write-lerobot: decomposer {decomposer} gives no instruction for segments {empty} of episode "
                f"{ep.name!r} (rdd takes them from its database's entries: build it from annotated episodes); "
                "pass --labeler signals (what the robot's hand and joint signals show), "
                "--labeler retrieval --label-db DB (a database with instructions) or "
                "--fallback-instruction TEMPLATE, e.g. '{task} (step {index} of {count})'"
            )
        out[int(ep.meta["episode_index"])] = ([tuple(s) for s in rec["segments"]], list(instr))
    return out


def read_segments_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """Episodes of a ``decompose`` output file by name."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise UsageError(f"{path}: no such file") from exc
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path}: invalid JSON ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("episodes"), list):
        raise UsageError(f"{path}: expected an object with an 'episodes' list (a decompose output)")
    out = {}
    for i, rec in enumerate(data["episodes"]):
        if not isinstance(rec, dict) or "episode" not in rec or "segments" not in rec:
            raise UsageError(f"{path}: episodes[{i}] lacks 'episode' or 'segments'")
        _check_numbers(path, i, rec)
        out[str(rec["episode"])] = rec
    return out


def _check_numbers(path: Path, i: int, rec: dict[str, Any]) -> None:
    """Segments (and num_frames) as JSON whole numbers: ``"12"`` or ``12.5`` is an error, never coerced."""
    def whole(v: Any) -> bool:
        return isinstance(v, int) and not isinstance(v, bool)

    where = f"{path}: episodes[{i}] ({rec['episode']!r})"
    if "num_frames" in rec and rec["num_frames"] is not None and not whole(rec["num_frames"]):
        raise UsageError(f"{where} field 'num_frames': expected a whole number, got {rec['num_frames']!r}")
    segments = rec["segments"]
    if not isinstance(segments, list):
        raise UsageError(f"{where} field 'segments': expected a list of [start, end] pairs, got {segments!r}")
    for j, seg in enumerate(segments):
        if not (isinstance(seg, list) and len(seg) == 2 and all(whole(v) for v in seg)):
            raise UsageError(f"{where} field 'segments'[{j}]: expected [start, end] as two whole numbers, got {seg!r}")
