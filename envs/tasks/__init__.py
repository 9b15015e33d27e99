"""The task registry: name -> Task class (one module per task)."""

from __future__ import annotations

from envs.tasks.base import Task
from envs.tasks.close_jar import CloseJar
from envs.tasks.insert_onto_square_peg import InsertOntoSquarePeg
from envs.tasks.light_bulb_in import LightBulbIn
from envs.tasks.meat_off_grill import MeatOffGrill
from envs.tasks.open_drawer import OpenDrawer
from envs.tasks.place_shape_in_shape_sorter import PlaceShapeInShapeSorter
from envs.tasks.push_buttons import PushButtons
from envs.tasks.put_item_in_drawer import PutItemInDrawer
from envs.tasks.reach_targets import ReachTargets
from envs.tasks.stack_blocks import StackBlocks
from envs.tasks.turn_tap import TurnTap

TASKS: dict[str, type[Task]] = {cls.name: cls for cls in (
    OpenDrawer, PutItemInDrawer, StackBlocks, MeatOffGrill, PushButtons, TurnTap,
    PlaceShapeInShapeSorter, CloseJar, InsertOntoSquarePeg, LightBulbIn, ReachTargets,
)}


def get_task(name: str) -> Task:
    """A fresh instance of the task called ``name``."""
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    return TASKS[name]()


def task_names(pretraining: bool | None = None) -> list[str]:
    """Registered task names; ``pretraining`` True/False selects planner-pretraining/evaluation tasks."""
    return [n for n, c in TASKS.items() if pretraining is None or c.pretraining == pretraining]
