"""A rendered instruction-following world for testing and measuring the planner without the simulator.

Each task is a scripted sequence of sub-task instructions whose wording depends on the goal (colours),
on what only the image shows (which side the drawer is on, whether it is already open, whether the
first button was already pressed; optionally where a block or button sits) and on how far the
episode has progressed. Episodes come out as
``rdd.data.episode.Episode`` with expert ``segments`` and ``instructions``, so the planner's data code
reads them exactly like demonstrations from the pybullet suite.

Pretraining tasks and evaluation tasks share skills (reading colours and positions) but order and
phrase their steps differently, so a planner pretrained only on the former must be finetuned to say
the latter's next step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rdd.data.episode import Episode

COLOURS: dict[str, tuple[int, int, int]] = {
    "red": (220, 40, 40),
    "green": (40, 180, 60),
    "blue": (40, 80, 220),
    "yellow": (230, 210, 40),
}
SLOTS = ("left", "middle", "right")
PRETRAIN_TASKS = ("pick_and_lift", "push_button", "open_drawer", "put_in_bin", "slide_to_target")
EVAL_TASKS = ("stack_blocks", "put_in_drawer", "push_buttons")

_BG = (235, 225, 205)
_GREY = (125, 125, 125)
_SLOT_X = {"left": 12, "middle": 32, "right": 52}  # centre x of each table slot (64 px canvas)
_BLOCK_Y = 48
_BUTTON_Y = 30
_DRAWER_X = {"left": 10, "right": 54}
_DRAWER_Y = 8
_BIN_XY = (32, 8)
_HOME = (32, 22)


@dataclass
class _State:
    """Everything the renderer draws; the expert mutates it step by step."""

    blocks: dict[str, tuple[float, float]] = field(default_factory=dict)  # colour -> centre
    buttons: dict[str, str] = field(default_factory=dict)  # colour -> slot
    pressed: set[str] = field(default_factory=set)
    drawer_side: str | None = None
    drawer_open: bool = False
    show_bin: bool = False
    pads: dict[str, str] = field(default_factory=dict)  # colour -> slot of a flat target pad
    gripper: tuple[float, float] = _HOME
    closed: bool = False
    held: str | None = None

    def copy(self) -> _State:
        """A deep enough copy for keyframe snapshots."""
        return _State(dict(self.blocks), dict(self.buttons), set(self.pressed), self.drawer_side,
                      self.drawer_open, self.show_bin, dict(self.pads), self.gripper, self.closed,
                      self.held)


def _rgb(name: str) -> tuple[int, int, int]:
    """Colour of an object named by its colour; unnamed distractors ("grey:<k>") are grey."""
    return COLOURS.get(name, _GREY)


def render(state: _State, size: int = 64) -> np.ndarray:
    """Draw ``state`` as a uint8 (size, size, 3) image (drawn at 64 px, resized when size differs)."""
    from PIL import Image, ImageDraw

    im = Image.new("RGB", (64, 64), _BG)
    d = ImageDraw.Draw(im)
    d.rectangle([0, 56, 63, 63], fill=(150, 120, 90))  # table edge
    if state.show_bin:
        x, y = _BIN_XY
        d.rectangle([x - 7, y - 5, x + 7, y + 5], outline=(90, 90, 90), width=2)
    if state.drawer_side is not None:
        x, y = _DRAWER_X[state.drawer_side], _DRAWER_Y
        d.rectangle([x - 8, y - 6, x + 8, y + 6], fill=(120, 80, 50))
        if state.drawer_open:
            d.rectangle([x - 7, y + 6, x + 7, y + 12], fill=(180, 140, 100))
            d.rectangle([x - 3, y + 12, x + 3, y + 14], fill=(40, 40, 40))
        else:
            d.rectangle([x - 3, y + 6, x + 3, y + 8], fill=(40, 40, 40))
    for name, slot in state.buttons.items():
        x = _SLOT_X[slot]
        d.ellipse([x - 6, _BUTTON_Y - 6, x + 6, _BUTTON_Y + 6], fill=_rgb(name),
                  outline=(30, 30, 30))
        if name in state.pressed:  # a pressed button shows its dark, sunken centre
            d.ellipse([x - 3, _BUTTON_Y - 3, x + 3, _BUTTON_Y + 3], fill=(20, 20, 20))
    for name, slot in state.pads.items():
        x = _SLOT_X[slot]
        d.rectangle([x - 8, _BLOCK_Y + 5, x + 8, _BLOCK_Y + 7], fill=_rgb(name))
    for name, (x, y) in state.blocks.items():
        d.rectangle([x - 5, y - 5, x + 5, y + 5], fill=_rgb(name))
    gx, gy = state.gripper
    gap = 3 if state.closed else 6
    d.rectangle([gx - gap - 2, gy - 12, gx - gap, gy - 5], fill=(60, 60, 60))
    d.rectangle([gx + gap, gy - 12, gx + gap + 2, gy - 5], fill=(60, 60, 60))
    d.rectangle([gx - gap - 2, gy - 14, gx + gap + 2, gy - 12], fill=(60, 60, 60))
    arr = np.asarray(im, dtype=np.uint8)
    if size != 64:
        arr = np.asarray(im.resize((size, size), Image.Resampling.BILINEAR), dtype=np.uint8)
    return arr


def _slot_of(x: float) -> str:
    return min(SLOTS, key=lambda s: abs(_SLOT_X[s] - x))


def _where(slot: str) -> str:
    """How an instruction names a place: 'on the left', 'in the middle', 'on the right'."""
    return "in the middle" if slot == "middle" else f"on the {slot}"


class _Script:
    """Records frames while the expert moves: each step interpolates the gripper to a target."""

    def __init__(self, state: _State, rng: np.random.Generator, size: int):
        self.state, self.rng, self.size = state, rng, size
        self.frames: list[np.ndarray] = [render(state, size)]
        self.keyframes: list[int] = []
        self.instructions: list[str] = []

    def step(self, instruction: str, target: tuple[float, float] | None = None, *,
             close: bool | None = None, effect=None) -> None:
        """Move (a few frames), then apply the gripper/effect change; the last frame is the keyframe."""
        s = self.state
        n = int(self.rng.integers(2, 5))
        start = s.gripper
        goal = target if target is not None else start
        for i in range(1, n + 1):
            # the step's first frame still shows the previous keyframe's state (as a simulator's
            # frame right after a keyframe does), so a segment's start frame does not leak its motion
            t = (i - 1) / (n - 1)
            s.gripper = (start[0] + (goal[0] - start[0]) * t, start[1] + (goal[1] - start[1]) * t)
            if s.held is not None:
                s.blocks[s.held] = (s.gripper[0], s.gripper[1] - 1)
            if i == n:
                if close is not None:
                    s.closed = close
                if effect is not None:
                    effect(s)
            self.frames.append(render(s, self.size))
        self.keyframes.append(len(self.frames) - 1)
        self.instructions.append(instruction)


def _pick_steps(sc: _Script, colour: str, *, lift: bool = True, where: bool = False) -> None:
    x, y = sc.state.blocks[colour]
    place = f" {_where(_slot_of(x))}" if where else ""
    sc.step(f"move to the {colour} block{place}", (x, y))

    def grab(s: _State) -> None:
        s.held = colour

    sc.step(f"grasp the {colour} block", close=True, effect=grab)
    if lift:
        sc.step(f"lift the {colour} block", (x, y - 16))


def _release(colour: str, dest: tuple[float, float] | None = None):
    def eff(s: _State) -> None:
        s.held = None
        if dest is not None:
            s.blocks[colour] = dest

    return eff


def _make_episode(task: str, rng: np.random.Generator, size: int,
                  where: bool) -> tuple[str, _Script]:
    cols = list(rng.permutation(list(COLOURS)))
    slots = list(rng.permutation(list(SLOTS)))
    st = _State()
    # Tasks about one coloured object show it among grey distractors (with ``where`` their
    # instructions say where it stands); tasks about two coloured objects name them by colour only.
    named = 2 if task in ("stack_blocks", "push_buttons", "slide_to_target") else 1
    n_objects = 2 if task == "put_in_drawer" else 3
    names = cols[:named] + [f"grey:{k}" for k in range(n_objects - named)]
    placed = dict(zip(names, slots[:n_objects], strict=True))
    if task in ("pick_and_lift", "put_in_bin", "stack_blocks", "put_in_drawer"):
        st.blocks = {n: (_SLOT_X[s], _BLOCK_Y) for n, s in placed.items()}
    if task == "slide_to_target":  # the second colour names a flat target pad, not a block
        pad = names.pop(1)
        st.pads = {pad: placed.pop(pad)}
        st.blocks = {n: (_SLOT_X[s], _BLOCK_Y) for n, s in placed.items()}
    if task in ("push_button", "push_buttons"):
        st.buttons = placed
        if task == "push_buttons" and rng.random() < 0.4:
            st.pressed.add(cols[0])  # the first button was already pressed: only the second is left
    if task in ("open_drawer", "put_in_drawer"):
        st.drawer_side = str(rng.choice(["left", "right"]))
        st.drawer_open = bool(task == "put_in_drawer" and rng.random() < 0.5)
    if task == "put_in_bin":
        st.show_bin = True
    sc = _Script(st, rng, size)
    c1, c2 = cols[0], cols[1]
    v = int(rng.integers(2))  # goal phrasing variation
    if task == "pick_and_lift":
        goal = [f"pick up the {c1} block", f"lift the {c1} block off the table"][v]
        _pick_steps(sc, c1, where=where)
    elif task == "put_in_bin":
        goal = [f"put the {c1} block in the bin", f"throw the {c1} block into the bin"][v]
        if rng.random() < 0.35:
            # the episode starts with the block already in the closed gripper: the image alone
            # says that moving to it and grasping it are done
            st.gripper, st.closed, st.held = st.blocks[c1], True, c1
            sc.frames = [render(st, size)]
            x, y = st.blocks[c1]
            sc.step(f"lift the {c1} block", (x, y - 16))
        else:
            _pick_steps(sc, c1, where=where)
        sc.step(f"move the {c1} block above the bin", (_BIN_XY[0], _BIN_XY[1] + 4))
        sc.step(f"release the {c1} block", close=False, effect=_release(c1, _BIN_XY))
    elif task == "slide_to_target":
        goal = [f"slide the {c1} block to the {c2} target",
                f"push the {c1} block onto the {c2} target"][v]
        x, y = st.blocks[c1]
        place = f" {_where(_slot_of(x))}" if where else ""
        sc.step(f"move to the {c1} block{place}", (x, y))
        tx = _SLOT_X[st.pads[c2]]

        def slide(s: _State) -> None:
            s.blocks[c1] = (tx, _BLOCK_Y)

        sc.step(f"push the {c1} block to the {c2} target", (tx, y), effect=slide)
        sc.step("move back up", _HOME)
    elif task == "stack_blocks":
        goal = [f"stack the {c1} block on the {c2} block",
                f"place the {c1} block on top of the {c2} block"][v]
        _pick_steps(sc, c1, where=False)
        x2, y2 = st.blocks[c2]
        sc.step(f"move the {c1} block above the {c2} block", (x2, y2 - 12))
        sc.step(f"release the {c1} block", close=False, effect=_release(c1, (x2, y2 - 10)))
    elif task in ("push_button", "push_buttons"):
        seq = [c1] if task == "push_button" else [c1, c2]
        goal = ([f"push the {c1} button", f"press the {c1} button"][v] if task == "push_button"
                else [f"push the {c1} button then the {c2} button",
                      f"press the {c1} button and then the {c2} button"][v])
        for c in seq:
            if c in st.pressed:
                continue
            x = _SLOT_X[st.buttons[c]]
            place = f" {_where(st.buttons[c])}" if where and task == "push_button" else ""
            sc.step(f"move above the {c} button{place}", (x, _BUTTON_Y - 8))

            def press(s: _State, c: str = c) -> None:
                s.pressed.add(c)

            sc.step(f"press the {c} button", (x, _BUTTON_Y - 2), effect=press)
        if task == "push_button":
            sc.step("move back up", _HOME)
    elif task in ("open_drawer", "put_in_drawer"):
        side = st.drawer_side
        hx, hy = _DRAWER_X[side], _DRAWER_Y + 14

        def pull(s: _State) -> None:
            s.drawer_open = True

        if task == "open_drawer":
            goal = ["open the drawer", "pull the drawer open"][v]
            sc.step(f"move to the drawer handle on the {side}", (hx, hy - 6))
            sc.step("grasp the drawer handle", close=True)
            sc.step("pull the drawer open", (hx, hy), effect=pull)
            sc.step("release the drawer handle", close=False)
        else:
            goal = [f"put the {c1} block in the drawer", f"store the {c1} block in the drawer"][v]
            if not st.drawer_open:
                sc.step(f"move to the drawer handle on the {side}", (hx, hy - 6))
                sc.step("pull the drawer open", (hx, hy), effect=pull)
            _pick_steps(sc, c1, lift=False, where=where)
            sc.step(f"move the {c1} block above the drawer", (hx, hy))
            sc.step(f"release the {c1} block", close=False, effect=_release(c1, (hx, hy - 4)))
    else:
        raise ValueError(f"unknown synthetic task {task!r}; known: {PRETRAIN_TASKS + EVAL_TASKS}")
    return goal, sc


def make_episode(task: str, seed: int, *, image_size: int = 64, where: bool = False) -> Episode:
    """One expert demonstration of ``task`` (seeded), with expert segments and instructions.

    ``where``: instructions about a single coloured block or button also say where it stands
    ("on the left"); off by default because a tiny planner trained on this CPU budget does not
    learn to localise small objects (measured: chance level), while large objects (the drawer's
    side, whether it is open, which button is pressed) it reads reliably.
    """
    rng = np.random.default_rng([seed, sum(map(ord, task))])
    goal, sc = _make_episode(task, rng, image_size, where)
    frames = np.stack(sc.frames)
    bounds = [0] + [k + 1 for k in sc.keyframes]
    segments = [(bounds[i], bounds[i + 1]) for i in range(len(sc.keyframes))]
    return Episode(name=f"{task}_{seed}", views={"front": frames}, goal=goal, task=task,
                   segments=segments, instructions=list(sc.instructions),
                   meta={"source": "planner.synthetic", "seed": seed})


def make_episodes(tasks: Sequence[str], seeds: Sequence[int], *, image_size: int = 64,
                  where: bool = False) -> list[Episode]:
    """Demonstrations for every (task, seed) pair."""
    return [make_episode(t, s, image_size=image_size, where=where) for t in tasks for s in seeds]
