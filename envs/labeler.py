"""Privileged sub-task labeler: any interval of an episode -> a sub-task instruction.

It reads only the interval's frames of the simulator's privileged record (object poses, held
object, articulation states) plus the gripper and end-effector tracks, never the expert's
segmentation or waypoints, so every decomposer's intervals are labelled by the same rules. It
plays the part of the paper's Gemini/GPT-4 labeler.

Vocabulary (the first rule that applies wins; X, Y are object labels such as "red block",
"top drawer handle", "plate"; D an articulation label such as "top drawer"):

============================================ ================================================
what happened in the interval                instruction
============================================ ================================================
a drawer opened / shut by >= 30 % of travel  "pull the D open" / "push the D shut"
a button went down / up >= 30 % of travel    "push the D" / "release the D"
a tap turned >= 30 % of its range            "turn the D"
X was released above Y (Y supports X)        "place the X onto the Y" ("into" for containers;
                                             Y = "stack of <colour> <type>s" when Y is a
                                             like-coloured object of X's type)
X was released into an open drawer D         "place the X in the D"
X was released with nothing under it         "put the X down"
X got grasped and rose >= 4 cm               "pick up the X"
X got grasped                                "grasp the X"
X held, ends over Y, not moving              "move the X above the Y"
X held, rose >= 4 cm, mostly vertically      "lift the X"
X held, over an open drawer D, not moving    "move the X above the D"
X held, otherwise                            "move the X toward the Y" (Y nearest to X)
X slid >= 3 cm sideways near the hand, unheld "push the X"
hand turned from pointing sideways to down   "turn the gripper to point down"
hand rose >= 4 cm, mostly vertically         "move the gripper up"
hand came >= 3 cm nearer Y and stopped there "reach for the Y" (Y nearest to the hand);
                                             "move above the Y" when the hand is closed
hand still moving at the interval's end      "move the gripper toward the Y" (Y nearest to
                                             where it is heading)
hand moved away from Y (nearest at start)    "move the gripper away from the <type of Y>"
otherwise                                    "keep the gripper still"
============================================ ================================================

For a full expert segment these are worded as the suite's expert instructions (``envs.tasks``):
"reach for the red block", "grasp the red block", "lift the red block", "move the red block
above the plate", "place the red block onto the stack of red blocks", "move the gripper up",
"reach for the top drawer handle", "grasp the top drawer handle", "pull the top drawer open",
"move the gripper away from the handle". ``docs/labeler.md`` lists the wording per task.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rdd.data.episode import Episode
from rdd.segments import Segment

# Destinations that take an object *into* them (a bulb into a lamp); everything else is "onto"
# (a lid onto a jar, a ring onto a peg, a block onto a plate).
CONTAINER_TYPES = frozenset({"lamp", "drawer", "box", "bin", "cupboard", "safe", "bowl", "basket",
                             "sorter", "dustpan", "rack", "holder"})

# Thresholds (metres unless stated); chosen well away from the expert's motions so a full
# segment's label does not flip on simulation noise.
ART_FRACTION = 0.3  # share of an articulation's travel that counts as "moved"
RISE = 0.04  # an upward move of at least this counts as lifting / moving up
PUSHED = 0.03  # a free object displaced this far was pushed
APPROACH = 0.03  # the hand got this much nearer an object: a reach
REACH_RADIUS = 0.25  # a reach ends at most this far from its object
MOVING = 0.004  # hand speed (m per frame) below which the hand counts as stopped
BRAKING = 0.6  # ... and, above it, the share of the interval's peak speed that means "not braking"
SUPPORT_MARGIN = 0.02  # horizontal slack when deciding that Y is under X
PUSH_REACH = 0.08  # a pushed object came this close to the hand
DRAWER_REACH = 0.3  # an object this near (horizontally) an open drawer's handle is over the drawer
TURN_DOWN = 45.0  # degrees the hand's approach axis came nearer straight down: a turn down
POINTING_DOWN = 20.0  # ... ending within this many degrees of straight down


@dataclass(frozen=True)
class _Scene:
    """Static scene description read from ``episode.meta``."""

    labels: list[str]
    types: list[str]
    colors: list[str]
    sizes: np.ndarray  # (K, 3)
    art_labels: list[str]
    art_kinds: list[str]
    art_closed: np.ndarray
    art_open: np.ndarray


def object_label(obj: Mapping[str, Any]) -> str:
    """Spoken label of a scene object: its name without a trailing index, underscores as spaces.

    A name "<colour>_<noun>" whose type is a longer phrase ending in that noun reads as
    "<colour> <type>" ("red_bulb" of type "light bulb" -> "red light bulb").
    """
    name = str(obj.get("name", ""))
    if not name:
        raise ValueError(f"privileged object description lacks a 'name': {obj!r}")
    base = re.sub(r"_\d+$", "", name)
    color, type_ = str(obj.get("color", "")), str(obj.get("type", ""))
    if (color and type_ and " " in type_ and base.startswith(color + "_")
            and base.split("_")[-1] == type_.split()[-1]):
        return f"{color} {type_}"
    return base.replace("_", " ")


def _scene(meta: Mapping[str, Any], where: str) -> _Scene:
    objects = meta.get("objects")
    if objects is None:
        raise ValueError(f"{where}: episode.meta lacks 'objects' (the privileged scene description)")
    arts = meta.get("articulations", [])
    return _Scene(
        labels=[object_label(o) for o in objects],
        types=[str(o.get("type", "")) for o in objects],
        colors=[str(o.get("color", "")) for o in objects],
        sizes=np.array([o.get("size", [0, 0, 0]) for o in objects], dtype=np.float64).reshape(-1, 3),
        art_labels=[object_label(a) for a in arts],
        art_kinds=[str(a.get("kind", "")) for a in arts],
        art_closed=np.array([a.get("closed", 0.0) for a in arts], dtype=np.float64),
        art_open=np.array([a.get("open", 1.0) for a in arts], dtype=np.float64),
    )


def _privileged(episode: Episode) -> Mapping[str, np.ndarray]:
    priv = episode.meta.get("privileged")
    if priv is None or "object_positions" not in priv:
        raise ValueError(
            f"episode {episode.name!r} has no privileged record (episode.meta['privileged'] with "
            "'object_positions', 'held_object', ...); the labeler needs simulator episodes from envs"
        )
    return priv


class PrivilegedLabeler:
    """Deterministic rule-based labeler over an interval of the privileged record."""

    name = "privileged"

    def label(self, episode: Episode, segment: Segment) -> str:
        """The instruction describing frames ``[start, end)`` of ``episode``."""
        start, end = int(segment[0]), int(segment[1])
        n = episode.num_frames
        if not 0 <= start < end <= n:
            raise ValueError(f"episode {episode.name!r}: segment {segment} outside [0, {n})")
        priv = _privileged(episode)
        scene = _scene(episode.meta, f"episode {episode.name!r}")
        sl = slice(start, end)
        pos = np.asarray(priv["object_positions"][sl], dtype=np.float64)
        held = np.asarray(priv["held_object"][sl], dtype=np.int64)
        arts = np.asarray(priv["articulation_states"][sl], dtype=np.float64).reshape(end - start, -1)
        if episode.ee_poses is None:
            raise ValueError(f"episode {episode.name!r} lacks ee_poses, which the labeler needs")
        hand = np.asarray(episode.ee_poses[sl, :3], dtype=np.float64)
        # Hand speeds (m per frame) from the frame before the interval to its last frame.
        track = np.asarray(episode.ee_poses[max(start - 1, 0):end, :3], dtype=np.float64)
        speeds = np.linalg.norm(np.diff(track, axis=0), axis=1) if len(track) > 1 else np.zeros(1)
        # Still moving at the end: fast, and not already braking (an arrival ends at a small
        # fraction of the motion's peak speed; an interval cut mid-motion ends near its peak).
        moving = bool(speeds[-1] >= MOVING and speeds[-1] >= BRAKING * speeds.max())
        if episode.gripper_open is None:
            raise ValueError(f"episode {episode.name!r} lacks gripper_open, which the labeler needs")
        gripper_open = bool(episode.gripper_open[end - 1] >= 0.5)
        tilt = _tilt_from_down(np.asarray(episode.ee_poses[[start, end - 1], 3:7], dtype=np.float64))
        return _describe(scene, pos, held, arts, hand, moving, gripper_open, tilt)

    def label_all(self, episode: Episode, segments: Sequence[Segment]) -> list[str]:
        """Labels of several intervals of one episode."""
        return [self.label(episode, s) for s in segments]


def _tilt_from_down(quats: np.ndarray) -> np.ndarray:
    """Degrees between the hand's approach axis (local z of xyzw ``quats``) and straight down."""
    x, y = quats[:, 0], quats[:, 1]
    approach_z = 1.0 - 2.0 * (x * x + y * y)
    return np.degrees(np.arccos(np.clip(-approach_z, -1.0, 1.0)))


def _describe(sc: _Scene, pos: np.ndarray, held: np.ndarray, arts: np.ndarray, hand: np.ndarray,
              moving: bool, gripper_open: bool, tilt: np.ndarray | None = None) -> str:
    k = len(sc.labels)
    # 1. Articulations: the one that moved most (relative to its travel).
    if arts.shape[1]:
        travel = np.where(np.abs(sc.art_open - sc.art_closed) > 1e-9, sc.art_open - sc.art_closed, 1.0)
        change = (arts[-1] - arts[0]) / travel
        m = int(np.argmax(np.abs(change)))
        if abs(change[m]) >= ART_FRACTION:
            kind, lab = sc.art_kinds[m], sc.art_labels[m]
            if kind == "drawer":
                return f"pull the {lab} open" if change[m] > 0 else f"push the {lab} shut"
            if kind == "button":
                return f"push the {lab}" if change[m] > 0 else f"release the {lab}"
            return f"turn the {lab}"
    held_start, held_end = int(held[0]), int(held[-1])
    ever_held = [int(i) for i in dict.fromkeys(held.tolist()) if i >= 0]
    # 2. Something was let go during the interval.
    released = [i for i in ever_held if i != held_end]
    if released:
        x = released[-1]
        y = _support(sc, pos[-1], x)
        if y is None:
            drawer = _open_drawer_at(sc, pos[-1], arts[-1], x)
            if drawer is not None:
                return f"place the {sc.labels[x]} in the {drawer}"
            return f"put the {sc.labels[x]} down"
        prep = "into" if sc.types[y].split(" ")[-1] in CONTAINER_TYPES else "onto"
        return f"place the {sc.labels[x]} {prep} the {_dest_label(sc, x, y)}"
    # 3. Holding X at the end.
    if held_end >= 0:
        x = held_end
        rise = pos[-1, x, 2] - pos[0, x, 2]
        if held_start != x:
            return f"pick up the {sc.labels[x]}" if rise >= RISE else f"grasp the {sc.labels[x]}"
        y = _below(sc, pos[-1], x)
        # "Above Y" only when Y is a new place, not what X was lifted off.
        if y is not None and y != _below(sc, pos[0], x) and not moving:
            return f"move the {sc.labels[x]} above the {_dest_label(sc, x, y)}"
        horiz = np.linalg.norm(pos[-1, x, :2] - pos[0, x, :2])
        if rise >= RISE and horiz <= 0.5 * rise:
            return f"lift the {sc.labels[x]}"
        drawer = _open_drawer_at(sc, pos[-1], arts[-1], x)
        if y is None and drawer is not None and not moving:
            return f"move the {sc.labels[x]} above the {drawer}"
        others = [j for j in range(k) if j != x]
        if others:
            y = min(others, key=lambda j: np.linalg.norm(pos[-1, j] - pos[-1, x]))
            return f"move the {sc.labels[x]} toward the {sc.labels[y]}"
        return f"move the {sc.labels[x]}"
    # 4. Nothing held at the end: did the hand push something sideways? (Objects that only drop,
    # e.g. after a release into a sorter, were not pushed.)
    if k:
        moved = np.linalg.norm(pos[-1, :, :2] - pos[0, :, :2], axis=1)
        touch = np.min(np.linalg.norm(pos - hand[:, None, :], axis=2), axis=0)
        moved = np.where(touch <= PUSH_REACH, moved, 0.0)
        j = int(np.argmax(moved))
        if moved[j] >= PUSHED:
            return f"push the {sc.labels[j]}"
    # 5. Hand motion only. A turn from a sideways grasp (a drawer handle) to pointing down gets
    # its own words: as "move the gripper up" its keyframe looked like a retreat above a placed
    # object, and the policy anchored it on the item instead of the hand.
    delta = hand[-1] - hand[0]
    if (tilt is not None and not moving and tilt[0] - tilt[1] >= TURN_DOWN
            and tilt[1] <= POINTING_DOWN):
        return "turn the gripper to point down"
    if delta[2] >= RISE and np.linalg.norm(delta[:2]) <= 0.5 * delta[2] and not moving:
        return "move the gripper up"
    if not k:
        return "move the gripper" if np.linalg.norm(delta) > APPROACH else "keep the gripper still"
    d_start = np.linalg.norm(pos[0] - hand[0], axis=1)
    d_end = np.linalg.norm(pos[-1] - hand[-1], axis=1)
    near = int(np.argmin(d_end))
    if moving:
        # Mid-motion: name the object the hand is heading for (best alignment with its motion).
        step = hand[-1] - hand[max(len(hand) - 2, 0)]
        to_obj = pos[-1] - hand[-1]
        cos = (to_obj @ step) / (np.linalg.norm(to_obj, axis=1) * np.linalg.norm(step) + 1e-12)
        score = cos - 0.5 * d_end  # prefer near objects among those ahead
        j = int(np.argmax(score))
        if cos[j] > 0.5:
            return f"move the gripper toward the {sc.labels[j]}"
        j0 = int(np.argmin(d_start))
        return f"move the gripper away from the {sc.types[j0] or sc.labels[j0]}"
    if d_end[near] <= REACH_RADIUS and d_start[near] - d_end[near] >= APPROACH:
        # An empty closed hand cannot grasp: it only moves above (e.g. to push a button).
        return f"reach for the {sc.labels[near]}" if gripper_open else f"move above the {sc.labels[near]}"
    j0 = int(np.argmin(d_start))
    if d_end[j0] - d_start[j0] >= APPROACH:
        return f"move the gripper away from the {sc.types[j0] or sc.labels[j0]}"
    if np.linalg.norm(delta) >= APPROACH:
        return f"move the gripper toward the {sc.labels[near]}"
    return "keep the gripper still"


def _below(sc: _Scene, pos: np.ndarray, x: int) -> int | None:
    """The object whose footprint lies under object ``x`` (highest first), or None."""
    best, best_z = None, -np.inf
    for j in range(len(sc.labels)):
        if j == x:
            continue
        half = 0.5 * sc.sizes[j, :2] + SUPPORT_MARGIN
        d = np.abs(pos[x, :2] - pos[j, :2])
        if np.all(d <= np.maximum(half, SUPPORT_MARGIN)) and pos[j, 2] < pos[x, 2] and pos[j, 2] > best_z:
            best, best_z = j, pos[j, 2]
    return best


def _support(sc: _Scene, pos: np.ndarray, x: int) -> int | None:
    """The object ``x`` rests on or is above at release (same footprint test as :func:`_below`)."""
    return _below(sc, pos, x)


def _open_drawer_at(sc: _Scene, pos: np.ndarray, arts: np.ndarray, x: int) -> str | None:
    """The open drawer object ``x`` is over or in (judged from the drawer's handle), or None.

    Drawers are articulations, not objects; a drawer "d" is located by its handle object, whose
    name starts with the drawer's name ("top_drawer" -> "top_drawer_handle").
    """
    best, best_d = None, np.inf
    for m, kind in enumerate(sc.art_kinds):
        span = sc.art_open[m] - sc.art_closed[m]
        if kind != "drawer" or abs(span) < 1e-9 or (arts[m] - sc.art_closed[m]) / span < ART_FRACTION:
            continue
        name = sc.art_labels[m].replace(" ", "_")
        for j, lab in enumerate(sc.labels):
            if j == x or not lab.replace(" ", "_").startswith(name):
                continue
            d = float(np.linalg.norm(pos[x, :2] - pos[j, :2]))
            if d <= DRAWER_REACH and pos[x, 2] >= pos[j, 2] - 0.08 and d < best_d:
                best, best_d = sc.art_labels[m], d
    return best


def _dest_label(sc: _Scene, x: int, y: int) -> str:
    """How a destination is named: a like object of the same colour reads as a stack."""
    if sc.types[y] and sc.types[y] == sc.types[x] and sc.colors[y] and sc.colors[y] == sc.colors[x]:
        return f"stack of {sc.colors[y]} {sc.types[y]}s"
    return sc.labels[y]
