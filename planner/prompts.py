"""RACER-style planner prompts (Dai et al., 2024): the same wording for training and for evaluation.

RACER's supervisor sees "<image>\\nThe task goal is: {goal}. In the previous step, the robot arm was
given the following instruction: {previous instruction}. ... Based on the visual observation and the
context, ... what's the next instruction for the robot?". The first step has no previous
instruction; RACER marks it as "The robot is about to start the task." We keep that wording, state
the robot's proprioceptive state s_t in words (the paper's planner is pi(l_t | s_t, o_t, l_{t-1}, L);
RACER's failure annotations, which our demonstrations do not carry, are left out) and make the answer
the next instruction itself.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

IMAGE_TOKEN = "<image>"
QUESTION = "Based on the visual observation and the context, what's the next instruction for the robot?"


def _sentence(text: str) -> str:
    text = " ".join(str(text).split())
    return text if text.endswith((".", "!", "?")) else text + "."


def robot_state(ee_pose: Any, gripper_open: Any) -> str:
    """The robot's proprioceptive state in words: whether the gripper is open, and the hand's height.

    ``ee_pose``: xyz (m) + quaternion; ``gripper_open``: 1 open, 0 closed (an array of one works too).
    The height is in whole centimetres: finer than a tabletop step, coarse enough to repeat.
    """
    z = float(np.asarray(ee_pose, dtype=np.float64).reshape(-1)[2])
    is_open = float(np.asarray(gripper_open, dtype=np.float64).reshape(-1)[0]) >= 0.5
    return f"the gripper is {'open' if is_open else 'closed'} and the hand is {round(z * 100)} cm high"


HEIGHT = re.compile(r"(the hand is )(-?\d+)( cm high)")


def shift_height(state: str | None, delta_cm: int) -> str | None:
    """A :func:`robot_state` text with the hand's height moved by ``delta_cm`` whole centimetres."""
    if state is None or not delta_cm:
        return state
    return HEIGHT.sub(lambda m: f"{m.group(1)}{int(m.group(2)) + int(delta_cm)}{m.group(3)}", state)


def state_text(state: str | Mapping[str, Any] | None) -> str | None:
    """``state`` as prompt text: a text as it is, an observation's ``ee_pose`` and ``gripper_open`` in words."""
    if state is None or isinstance(state, str):
        return state
    return robot_state(state["ee_pose"], state["gripper_open"])


def user_prompt(goal: str, previous_instruction: str | None, question: str | None = None,
                scene: str | None = None, state: str | None = None) -> str:
    """The user turn: image placeholder, goal, previous instruction (or the start marker), the robot's
    state, question.

    ``question``: another question about the image instead of the planner's (a scene caption's).
    ``scene``: the planner's own description of the image (``describe_scene``), stated before the question.
    ``state``: the robot's state in words (:func:`robot_state`).
    """
    if question is not None:
        if not str(question).strip():
            raise ValueError("a question prompt needs a non-empty question")
        return f"{IMAGE_TOKEN}\n{' '.join(str(question).split())}"
    if not str(goal).strip():
        raise ValueError("planner prompt needs a non-empty task goal")
    parts = [f"{IMAGE_TOKEN}\nThe task goal is: {_sentence(goal)}"]
    if previous_instruction is None or not str(previous_instruction).strip():
        parts.append("This is the first step and the robot is about to start the task.")
    else:
        parts.append("In the previous step, the robot arm was given the following instruction: "
                     f"{_sentence(previous_instruction)}")
    if state is not None and str(state).strip():
        parts.append(f"The robot: {_sentence(state)}")
    if scene is not None and str(scene).strip():
        parts.append(f"The scene: {_sentence(scene)}")
    parts.append(QUESTION)
    return " ".join(parts)


def render_prompt(tokenizer, goal: str, previous_instruction: str | None, question: str | None = None,
                  scene: str | None = None, state: str | None = None) -> str:
    """The chat-formatted prompt text, ending where the assistant's answer starts."""
    messages = [{"role": "user", "content": user_prompt(goal, previous_instruction, question, scene, state)}]
    return tokenizer.apply_chat_template(messages, tokenize=False, add_generation_prompt=True)


def render_target(tokenizer, goal: str, previous_instruction: str | None, target: str,
                  question: str | None = None, scene: str | None = None, state: str | None = None) -> str:
    """The text the model must produce after the prompt (answer plus the template's end marker)."""
    target = " ".join(str(target).split())
    if not target:
        raise ValueError("planner target instruction is empty")
    prompt = render_prompt(tokenizer, goal, previous_instruction, question, scene, state)
    messages = [{"role": "user", "content": user_prompt(goal, previous_instruction, question, scene, state)},
                {"role": "assistant", "content": target}]
    full = tokenizer.apply_chat_template(messages, tokenize=False)
    if not full.startswith(prompt):
        raise ValueError("the tokenizer's chat template renders the conversation with a different "
                         "prefix than the generation prompt; cannot split prompt from answer")
    return full[len(prompt):]


def clean_output(text: str) -> str:
    """First line of a generation, whitespace collapsed, trailing full stop removed."""
    line = next((ln for ln in str(text).splitlines() if ln.strip()), "")
    line = " ".join(line.split())
    for prefix in ("The next instruction is:", "Next instruction:"):
        if line.lower().startswith(prefix.lower()):
            line = line[len(prefix):].strip()
    return line.rstrip(".").strip()
