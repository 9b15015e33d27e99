"""Paired differences between methods with bootstrap confidence intervals.

Every method of a table is evaluated on the same seeded episodes (run seed, task, environment
seed), so a method's success can be compared with a reference method's episode by episode. The
difference of two methods' average success (the mean over tasks of per-task success rates) is the
mean over tasks of the per-task mean of paired differences; its 95% interval is a percentile
bootstrap that resamples the paired episodes with replacement within each task (tasks keep equal
weight, as in the paper's average) over all seeds together.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

EpisodeKey = tuple[int, str, int]  # (run seed, task, environment seed)


@dataclass(frozen=True)
class PairedDifference:
    """``method - reference`` in average success (fractions), with its bootstrap interval."""

    method: str
    reference: str
    mean: float
    low: float
    high: float
    pairs: int
    level: float

    @property
    def significant(self) -> bool:
        """True when the interval excludes zero."""
        return self.low > 0 or self.high < 0


def stratified_bootstrap_mean(
    strata: Sequence[np.ndarray], n_boot: int = 10_000, level: float = 0.95, seed: int = 0
) -> tuple[float, float, float]:
    """Mean over strata of each stratum's mean, and its percentile-bootstrap interval.

    Each bootstrap replicate resamples every stratum's values with replacement (same size).
    """
    if not strata or any(len(s) == 0 for s in strata):
        raise ValueError("bootstrap: every stratum needs at least one value")
    if not 0 < level < 1:
        raise ValueError(f"bootstrap: level must be in (0, 1), got {level}")
    if n_boot < 1:
        raise ValueError(f"bootstrap: n_boot must be >= 1, got {n_boot}")
    rng = np.random.default_rng(seed)
    point = float(np.mean([np.mean(s) for s in strata]))
    reps = np.zeros(n_boot)
    for s in strata:
        s = np.asarray(s, dtype=np.float64)
        idx = rng.integers(0, s.size, size=(n_boot, s.size))
        reps += s[idx].mean(axis=1)
    reps /= len(strata)
    alpha = (1 - level) / 2
    low, high = np.quantile(reps, [alpha, 1 - alpha], method="inverted_cdf")
    return point, float(low), float(high)


def episode_outcomes(episodes_by_seed: Mapping[int, Sequence[Mapping]]) -> dict[EpisodeKey, float]:
    """``{(run seed, task, env seed): success}`` from each run seed's per-episode rows."""
    out: dict[EpisodeKey, float] = {}
    for run_seed, episodes in episodes_by_seed.items():
        for ep in episodes:
            key = (int(run_seed), str(ep["task"]), int(ep["seed"]))
            if key in out:
                raise ValueError(f"episode {key} appears twice in the runs of one method")
            out[key] = float(bool(ep["success"]))
    return out


def paired_difference(
    method: str,
    outcomes: Mapping[EpisodeKey, float],
    reference: str,
    ref_outcomes: Mapping[EpisodeKey, float],
    n_boot: int = 10_000,
    level: float = 0.95,
    seed: int = 0,
) -> PairedDifference:
    """``method - reference`` over the episodes both were evaluated on (the sets must be equal)."""
    if set(outcomes) != set(ref_outcomes):
        only_m = sorted(set(outcomes) - set(ref_outcomes))[:3]
        only_r = sorted(set(ref_outcomes) - set(outcomes))[:3]
        raise ValueError(
            f"paired comparison {method!r} vs {reference!r}: the evaluation episodes differ "
            f"(only in {method}: {only_m}; only in {reference}: {only_r})"
        )
    by_task: dict[str, list[float]] = defaultdict(list)
    for key in sorted(outcomes):
        by_task[key[1]].append(outcomes[key] - ref_outcomes[key])
    strata = [np.asarray(v) for _, v in sorted(by_task.items())]
    mean, low, high = stratified_bootstrap_mean(strata, n_boot=n_boot, level=level, seed=seed)
    return PairedDifference(method, reference, mean, low, high, len(outcomes), level)
