"""A small real run of the RDD library on synthetic demonstrations with known sub-task boundaries.

Each synthetic task is a chain of waypoints in a latent space; a demonstration moves along the chain
piecewise linearly (one sub-task per leg, a random number of frames each, plus noise) and is seen by
two fixed random nonlinear "cameras" (front, wrist). Training demonstrations, cut at their true
boundaries, fill a sub-task database; a new demonstration is then decomposed by retrieval, and the
segments found are compared with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rdd.database.model import SubtaskDatabase
from rdd.encoders.embed import concat_views
from rdd.segments import Segment, boundaries


@dataclass
class SyntheticWorld:
    """Latent waypoint chains per task and two fixed random view projections."""

    waypoints: dict[str, np.ndarray]  # task -> (K+1, m) waypoints; leg k is sub-task k
    subtask_names: dict[str, list[str]]
    projections: tuple[np.ndarray, np.ndarray]
    noise: float

    @classmethod
    def make(cls, seed: int = 0, tasks: int = 3, legs: tuple[int, int] = (3, 5), latent_dim: int = 16,
             view_dim: int = 64, noise: float = 0.02) -> SyntheticWorld:
        """Random tasks of ``legs`` sub-tasks each, seen through two ``view_dim``-d views."""
        rng = np.random.default_rng(seed)
        verbs = ["reach", "grasp", "lift", "move", "place", "push", "open", "turn"]
        objects = ["red block", "blue cup", "drawer", "lid", "green ball", "handle"]
        waypoints, names = {}, {}
        for t in range(tasks):
            k = int(rng.integers(legs[0], legs[1] + 1))
            task = f"task_{t}"
            waypoints[task] = rng.normal(size=(k + 1, latent_dim))
            names[task] = [f"{verbs[rng.integers(len(verbs))]} the {objects[rng.integers(len(objects))]}"
                           for _ in range(k)]
        proj = (rng.normal(size=(latent_dim, view_dim)), rng.normal(size=(latent_dim, view_dim)))
        return cls(waypoints, names, proj, noise)

    def demo(self, task: str, rng: np.random.Generator, length_range: tuple[int, int] = (12, 30)
             ) -> tuple[np.ndarray, list[Segment]]:
        """Frame vectors (T, 2*view_dim) of one new demonstration of ``task`` and its true segments."""
        wp = self.waypoints[task]
        latents, segments, start = [], [], 0
        for k in range(wp.shape[0] - 1):
            n = int(rng.integers(length_range[0], length_range[1] + 1))
            alpha = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
            latents.append(wp[k] + alpha * (wp[k + 1] - wp[k]))
            segments.append((start, start + n))
            start += n
        x = np.concatenate(latents)
        x = x + self.noise * rng.normal(size=x.shape)
        views = [np.tanh(x @ p) for p in self.projections]
        return concat_views(views), segments


def build_synthetic_database(world: SyntheticWorld, demos_per_task: int, rng: np.random.Generator
                             ) -> tuple[SubtaskDatabase, dict[str, list]]:
    """A database of every true sub-task of ``demos_per_task`` training demos per task."""
    begin, end, durations, labels = [], [], [], []
    meta: dict[str, list] = {"episodes": [], "tasks": [], "starts": [], "ends": []}
    demos: dict[str, list] = {}
    for task in world.waypoints:
        for i in range(demos_per_task):
            fv, segs = world.demo(task, rng)
            demos.setdefault(task, []).append((fv, segs))
            for k, (s, e) in enumerate(segs):
                begin.append(fv[s])
                end.append(fv[e - 1])
                durations.append(e - 1 - s)
                labels.append(world.subtask_names[task][k])
                meta["episodes"].append(f"{task}/train_{i}")
                meta["tasks"].append(task)
                meta["starts"].append(s)
                meta["ends"].append(e)
    db = SubtaskDatabase.from_arrays(
        np.stack(begin), np.stack(end), np.asarray(durations), labels,
        {"encoder": "synthetic", "weights_id": "none", "views": ["front", "wrist"], **meta},
    )
    return db, demos


def boundary_errors(found: list[Segment], truth: list[Segment]) -> list[int] | None:
    """Frame offsets of found cut points from the true ones (None when their counts differ)."""
    a, b = boundaries(found), boundaries(truth)
    if len(a) != len(b):
        return None
    return [int(x) - int(y) for x, y in zip(a, b, strict=True)]


def assemble_from_database(demos: dict[str, list], picks: list[tuple[str, int, int]]
                           ) -> tuple[np.ndarray, list[Segment], list[str]]:
    """A demonstration made of copies of training sub-tasks ``(task, demo index, sub-task index)``."""
    parts, truth, names, start = [], [], [], 0
    for task, i, k in picks:
        fv, segs = demos[task][i]
        s, e = segs[k]
        parts.append(fv[s:e])
        truth.append((start, start + e - s))
        names.append(f"{task}/train_{i} [{s}, {e})")
        start += e - s
    return np.concatenate(parts), truth, names


def _report(title: str, truth: list[Segment], result) -> dict:
    errors = boundary_errors(result.segments, truth)
    print(title)
    print(f"  true segments  : {truth}")
    print(f"  RDD segments   : {result.segments}")
    print(f"  boundary error : {errors if errors is not None else 'different number of segments'}")
    for seg, n, j in zip(result.segments, result.neighbours, result.scores, strict=True):
        print(f"  {str(seg):>10} -> '{n['instruction']}' ({n['episode']} [{n['start']}, {n['end']}),"
              f" distance {n['distance']:.4f}, J {j:.3f})")
    print(f"  novelty Delta  : {result.novelty:.4f}")
    return errors


def run_demo(seed: int = 0, demos_per_task: int = 5, index: str = "exact", verbose: bool = True) -> dict:
    """Build a synthetic database, decompose two new demonstrations, print and return the comparison.

    The first is assembled from copies of database sub-tasks in a new order (RDD must recover it
    exactly); the second is a fresh demonstration of a known task (new noise and sub-task lengths).
    """
    from rdd.decomposers.rdd import RDDDecomposer

    rng = np.random.default_rng(seed)
    world = SyntheticWorld.make(seed=seed)
    db, demos = build_synthetic_database(world, demos_per_task, rng)
    decomposer = RDDDecomposer(db, alpha=1.0, min_len=2, max_len=60, index=index)
    tasks = sorted(world.waypoints)
    picks = []
    for _ in range(4):
        task = tasks[int(rng.integers(len(tasks)))]
        i = int(rng.integers(demos_per_task))
        picks.append((task, i, int(rng.integers(len(demos[task][i][1])))))
    fv_a, truth_a, names = assemble_from_database(demos, picks)
    res_a = decomposer.decompose_embeddings(fv_a)
    task = tasks[int(rng.integers(len(tasks)))]
    fv_f, truth_f = world.demo(task, rng)
    res_f = decomposer.decompose_embeddings(fv_f)
    if verbose:
        # "backend": the summary's word for the index since its first version (scripts compare it)
        print(f"RDD demo: {len(db)} database sub-tasks from {demos_per_task} demos x {len(tasks)} "
              f"synthetic tasks, {db.frame_dim}-d frame vectors (2 views), backend {index}")
    err_a = _report(f"[1] {fv_a.shape[0]} frames assembled from database sub-tasks {names}",
                    truth_a, res_a) if verbose else boundary_errors(res_a.segments, truth_a)
    err_f = _report(f"[2] a fresh {task} demonstration of {fv_f.shape[0]} frames (new noise and lengths)",
                    truth_f, res_f) if verbose else boundary_errors(res_f.segments, truth_f)

    def summary(fv, truth, res, errors) -> dict:
        return {
            "num_frames": int(fv.shape[0]), "truth": truth, "segments": res.segments,
            "keyframes": res.keyframes, "boundary_errors": errors, "exact": res.segments == truth,
            "matched": [{k: n[k] for k in ("entry", "episode", "start", "end", "instruction", "distance")}
                        for n in res.neighbours],
            "scores": res.scores, "novelty": res.novelty,
        }

    return {
        # "backend": the summary's key for the index since its first version (scripts read it)
        "database_entries": len(db), "backend": index,
        "assembled": summary(fv_a, truth_a, res_a, err_a),
        "fresh": {"task": task, **summary(fv_f, truth_f, res_f, err_f)},
    }
