"""``python run.py --help``: what can be chosen (config groups and their options, modes, tasks).

Built from the config tree and the code, so it cannot drift from them: the groups are those the
primary config's defaults list names (groups used only inside experiments, such as ``scale``, are
not choices), the modes come from the typed schema, the tasks from the suite's registry.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

CONF = Path(__file__).resolve().parents[2] / "conf"


def choosable_groups(conf: Path = CONF) -> dict[str, list[str]]:
    """Group -> options, for the groups named in ``conf/config.yaml``'s defaults list."""
    defaults = OmegaConf.to_container(OmegaConf.load(conf / "config.yaml"))["defaults"]
    groups = [next(iter(d)) for d in defaults if isinstance(d, dict)]
    groups = [g for g in groups if not g.startswith(("override", "hydra")) and (conf / g).is_dir()]
    return {g: sorted(p.stem for p in (conf / g).glob("*.yaml")) for g in sorted(groups)}


def help_text() -> str:
    """The help page of ``run.py``."""
    from envs.tasks import task_names
    from experiments.config.schemas import Mode

    lines = ["python run.py [group=option ...] [key=value ...]     one run",
             "python run.py -m group=a,b key=1,2 ...               a sweep (one job per combination)",
             "", "Config groups (group=option):"]
    lines += [f"  {g}: {', '.join(opts)}" for g, opts in choosable_groups().items()]
    lines += ["", f"mode: {', '.join(m.name for m in Mode)}",
              f"tasks (evaluation): {', '.join(task_names(pretraining=False))}",
              f"data.pretrain_tasks (planner pretraining): {', '.join(task_names(pretraining=True))}",
              "", "Common keys: seed=N, tasks=[a,b], eval.episodes_per_task=N, threads=N,",
              "  paths.cache_dir=DIR (the stage cache; default $RDD_CACHE_DIR, else ./.cache/rdd).",
              "python run.py --cfg job             the whole composed config (every key)",
              "python run.py --hydra-help          Hydra's own flags",
              "Reference: docs/harness.md"]
    return "\n".join(lines)
