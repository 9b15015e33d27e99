"""A second annotation of LeRobot hand data, by a procedure independent of the project's expert rule.

The expert rule (``rdd/data/hand_events.py``, ``--option rule=hands``) follows each hand's *level* (the
mean of all its dims) with a zigzag filter of relative size ``hand_delta``, cuts half way through
each move and adds cuts at arm rests. This script annotates the same episodes another way, to have
something to measure the rule against:

1. A hand's signal is the **median of its finger dims**, in the joint's own units (on a Unitree G1
   Inspire hand 1 = open, 0 = closed; the four finger dims pinky, ring, middle, index, not the thumb's).
2. **Hysteresis with fixed thresholds**: the hand is *open* once the signal rises above
   ``--open-above`` (0.75) and *closed* once it falls below ``--closed-below`` (0.65); in between it
   keeps its state. Its state at frame 0 is the nearer one (above or below the middle of the two).
   The thresholds were fixed before any agreement was measured, from the joint's range and the
   posture of a hand holding the bottle (fingers at 0.55-0.65), not fitted to the rule.
3. **Dwell**: a state that lasts less than ``--min-dwell-s`` (0.2 s, from the dataset's fps) is a
   flicker and is undone, as is one that the episode ends before it lasts that long.
4. A **cut** is the first frame of each new state. Cuts of different hands less than the dwell
   apart are one (their mean frame); a cut less than the dwell from either end of the episode is
   dropped. Nothing else cuts: the arms are not looked at.

Each segment is named by the change that ends it ("open the right hand"); the last one, which no
change ends, "hold the right hand closed" (the state it ends in). The sub-tasks are written as
LeRobot v3.0 ``language_persistent`` rows into a new copy of each dataset (``rdd.data.lerobot.write``;
the source is never written), read back with the reader ``build-db --segments subtasks`` uses, and
saved as a ``decompose``-style JSON, so that ``python -m rdd evaluate --gt`` can score the rule
against it. Only the parquet files are read; no video is decoded. Example:

    python benchmarks/annotate_hand_hysteresis.py --data D1 --data D2 --copies OUT --json hands.json
    python -m rdd decompose --format lerobot --data D1 --reader-option skip_missing=true \\
        --decomposer expert --out rule1.json          # likewise rule2.json for D2
    python -m rdd evaluate --pred rule=rule1.json rule=rule2.json --gt hands.json --tolerance 5
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rdd.atomic import write_json_atomic
from rdd.data.lerobot.dataset import LeRobotDataset
from rdd.data.lerobot.reader import episode_name, load_episodes
from rdd.data.lerobot.write import write_subtasks
from rdd.errors import InputError

OPEN_ABOVE, CLOSED_BELOW, MIN_DWELL_S = 0.75, 0.65, 0.2
FINGERS = ("pinky", "ring", "middle", "index")


def hysteresis_states(signal: np.ndarray, open_above: float, closed_below: float) -> np.ndarray:
    """Per frame, True while the hand is open: it opens above ``open_above``, closes below ``closed_below``."""
    x = np.asarray(signal, dtype=np.float64).reshape(-1)
    out = np.zeros(x.size, dtype=bool)
    state = bool(x.size and x[0] >= (open_above + closed_below) / 2)
    for i, v in enumerate(x):
        if state and v < closed_below:
            state = False
        elif not state and v > open_above:
            state = True
        out[i] = state
    return out


def debounced_changes(states: np.ndarray, min_dwell: int) -> list[tuple[int, bool]]:
    """(frame, opens) of each state change that lasts at least ``min_dwell`` frames; shorter states
    (also one the episode cuts short) are undone, as if the hand had kept its previous state."""
    s = np.asarray(states, dtype=bool)
    if s.size == 0:
        return []
    edges = np.flatnonzero(np.diff(s.astype(np.int8))) + 1
    starts, ends = [0, *edges.tolist()], [*edges.tolist(), s.size]
    kept: list[list] = [[0, bool(s[0])]]  # [start, state] of the runs kept
    for a, b in zip(starts[1:], ends[1:], strict=True):
        state = bool(s[a])
        if b - a < min_dwell or state == kept[-1][1]:
            continue  # a flicker, or the state the hand is already in after an undone flicker
        kept.append([a, state])
    return [(a, state) for a, state in kept[1:]]


def hand_cuts(changes: Sequence[tuple[int, int, bool]], num_frames: int, min_dwell: int) -> list[tuple[int, list]]:
    """Cuts from the changes ``(frame, hand, opens)`` of every hand: changes less than ``min_dwell``
    apart are one cut at their mean frame; cuts within ``min_dwell`` of either end are dropped.
    Returns (cut frame, the changes it stands for)."""
    groups: list[list[tuple[int, int, bool]]] = []
    for c in sorted(changes):
        if groups and c[0] - groups[-1][0][0] < min_dwell:
            groups[-1].append(c)
        else:
            groups.append([c])
    cuts = [(int(round(np.mean([c[0] for c in g]))), g) for g in groups]
    return [(f, g) for f, g in cuts if min_dwell <= f <= num_frames - min_dwell]


def annotate(signals: dict[str, np.ndarray], fps: float, open_above: float = OPEN_ABOVE,
             closed_below: float = CLOSED_BELOW, min_dwell_s: float = MIN_DWELL_S) -> tuple[list, list[str]]:
    """Segments and instructions of one episode from its hands' signals (name -> (T,) signal)."""
    if not closed_below < open_above:
        raise InputError(f"--closed-below {closed_below} must be below --open-above {open_above}")
    names = list(signals)
    t = len(next(iter(signals.values())))
    dwell = max(1, int(round(min_dwell_s * fps)))
    per_hand = {n: debounced_changes(hysteresis_states(signals[n], open_above, closed_below), dwell) for n in names}
    changes = [(f, h, opens) for h, n in enumerate(names) for f, opens in per_hand[n]]
    # The state each hand ends in: that of its last change, else the one it starts in.
    final = {n: per_hand[n][-1][1] if per_hand[n] else bool(signals[n][0] >= (open_above + closed_below) / 2)
             for n in names}
    cuts = hand_cuts(changes, t, dwell)
    bounds = [0, *[f for f, _ in cuts], t]
    segments = [(bounds[k], bounds[k + 1]) for k in range(len(bounds) - 1)]

    def hand(n: str) -> str:
        return f"the {n} hand" if n in ("left", "right") else f"the {n}"

    instructions = []
    for _, group in cuts:
        instructions.append(" and ".join(f"{'open' if o else 'close'} {hand(names[h])}" for _, h, o in group))
    instructions.append(" and ".join(f"hold {hand(n)} {'open' if final[n] else 'closed'}" for n in names))
    return segments, instructions


def parse_hands(items: Sequence[str] | None, state_names: Sequence[str], where: str) -> dict[str, list[int]]:
    """``NAME=DIMS`` (``right=20-23``, ``gripper=3``) -> dims; none given: each side's finger dims by name."""
    if items:
        out = {}
        for item in items:
            name, sep, dims = item.partition("=")
            m = re.fullmatch(r"(\d+)(?:-(\d+))?", dims.strip())
            if not sep or not name or m is None:
                raise InputError(f"--hand {item!r}: expected NAME=DIM or NAME=FIRST-LAST, e.g. right=20-23")
            lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
            if hi < lo or hi >= len(state_names):
                raise InputError(f"--hand {item!r}: dims {lo}-{hi} outside observation.state's "
                                 f"{len(state_names)} dims ({where})")
            out[name] = list(range(lo, hi + 1))
        return out
    out = {}
    for side in ("left", "right"):
        dims = [i for i, n in enumerate(state_names)
                if side in n.lower() and "hand" in n.lower() and any(f in n.lower() for f in FINGERS)]
        if dims:
            out[side] = dims
    if not out:
        raise InputError(f"{where}: no observation.state name holds a side, 'hand' and a finger "
                         f"({', '.join(FINGERS)}); name the dims with --hand NAME=FIRST-LAST")
    return out


def state_names(ds: LeRobotDataset) -> list[str]:
    """The dims' names of ``observation.state`` (LeRobot may nest them one list deep)."""
    names = (ds.features.get("observation.state") or {}).get("names")
    if isinstance(names, dict):
        names = next(iter(names.values()), None)
    if isinstance(names, list) and names and isinstance(names[0], list):
        names = names[0]
    if not isinstance(names, list):
        raise InputError(f"{ds.info_path}: feature observation.state names no dims")
    return [str(n) for n in names]


def episode_states(ds: LeRobotDataset, ep: int) -> np.ndarray:
    """(T, D) observation.state of episode ``ep``, in frame order, read from its parquet file."""
    import pyarrow.parquet as pq

    path = ds.data_file(ep)
    table = pq.read_table(path, columns=["observation.state", "episode_index", "frame_index"])
    index = np.asarray(table.column("episode_index").to_numpy())
    order = np.flatnonzero(index == ep)
    order = order[np.argsort(np.asarray(table.column("frame_index").to_numpy())[order], kind="stable")]
    return np.asarray(table.column("observation.state").to_pylist(), dtype=np.float64)[order]


def annotate_dataset(root: Path, hands: Sequence[str] | None, **thresholds: float) -> dict[int, tuple[list, list[str]]]:
    """Episode index -> (segments, instructions) for every episode of ``root`` whose data file exists."""
    ds = LeRobotDataset(root)
    names = state_names(ds)
    dims = parse_hands(hands, names, str(ds.info_path))
    out = {}
    for ep in sorted(ds.episodes):
        if not ds.data_file(ep).is_file():
            continue
        states = episode_states(ds, ep)
        out[ep] = annotate({n: np.median(states[:, d], axis=1) for n, d in dims.items()}, ds.fps, **thresholds)
    if not out:
        raise InputError(f"{root}: no episode has its data file")
    return out


def main(argv: Sequence[str] | None = None) -> dict[str, dict]:
    """Annotate each ``--data`` dataset into a copy under ``--copies``; write the read-back segments to ``--json``."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--data", action="append", required=True, help="a LeRobot dataset (repeat for several)")
    p.add_argument("--copies", required=True, help="new folder: one annotated v3.0 copy per --data, by its name")
    p.add_argument("--json", required=True, help="the read-back segments of every episode, as decompose writes them")
    p.add_argument("--hand", action="append", metavar="NAME=FIRST-LAST",
                   help="a hand's dims in observation.state (default: each side's finger dims, by name)")
    p.add_argument("--open-above", type=float, default=OPEN_ABOVE)
    p.add_argument("--closed-below", type=float, default=CLOSED_BELOW)
    p.add_argument("--min-dwell-s", type=float, default=MIN_DWELL_S)
    args = p.parse_args(argv)
    copies, out_json = Path(args.copies), Path(args.json)
    if copies.exists() or out_json.exists():
        raise InputError(f"{copies if copies.exists() else out_json} already exists (refusing to replace it)")
    roots = [Path(d) for d in args.data]
    if len({r.name for r in roots}) != len(roots):
        raise InputError("--data: two datasets share a folder name (their copies would collide)")
    thresholds = {"open_above": args.open_above, "closed_below": args.closed_below, "min_dwell_s": args.min_dwell_s}
    records = []
    for root in roots:
        subtasks = annotate_dataset(root, args.hand, **thresholds)
        copy = write_subtasks(root, copies / root.name, subtasks, version="v3.0")
        back = {e.name: e for e in load_episodes(copy, episodes=sorted(subtasks))}
        for ep, (segments, instructions) in sorted(subtasks.items()):
            got = back[episode_name(ep)]
            if got.segments != segments or got.instructions != instructions:
                raise RuntimeError(f"{copy}: episode {ep} reads back as {got.segments} {got.instructions}, "
                                   f"not {segments} {instructions}")
            records.append({"episode": got.name, "num_frames": got.num_frames,
                            "segments": [list(s) for s in got.segments], "instructions": got.instructions,
                            "source": str(root)})
        print(f"wrote {copy}: {len(subtasks)} episodes annotated (language_persistent)")
    result = {"config": {"procedure": "hand hysteresis", **thresholds, "hands": args.hand or "finger dims by name",
                         "data": [str(r) for r in roots]}, "episodes": records}
    write_json_atomic(out_json, result)
    print(f"wrote {out_json}: {len(records)} episodes")
    return result


if __name__ == "__main__":
    try:
        main()
    except (InputError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
