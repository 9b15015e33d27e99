"""Shared expert demonstrations for the envs tests (recorded once per session, no images)."""

from __future__ import annotations

import pytest

_CACHE: dict = {}


def expert_demo(task: str, seed: int):
    """The (cached) no-render expert result for (task, seed)."""
    from envs.expert import run_expert

    key = (task, seed)
    if key not in _CACHE:
        _CACHE[key] = run_expert(task, seed, render=False)
    return _CACHE[key]


@pytest.fixture(scope="session")
def demo():
    """Function returning the cached expert result for (task, seed)."""
    return expert_demo
