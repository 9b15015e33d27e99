"""The harness's calls into the other packages (envs, policy, planner, rdd), in one place.

Each function here is the single point where a stage meets a package's public API, so the
stages (``graph.py``, ``planner_stages.py``, ``modes.py``) read as data flow and a package's API
change is fixed here only.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omegaconf import DictConfig, OmegaConf

from experiments.cache.store import read_json
from experiments.run.logs import progress_enabled
from rdd.atomic import write_json_atomic
from rdd.segments import Segment

if TYPE_CHECKING:
    from experiments.config.instantiate import Resolved

PLANNER_FILE = "planner.json"


def _plain(node: Any) -> Any:
    if isinstance(node, DictConfig):
        return OmegaConf.to_container(node, resolve=True)
    return node


# --- env -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EnvInfo:
    """Task lists of the suite."""

    all_tasks: tuple[str, ...]
    evaluation_tasks: tuple[str, ...]
    pretraining_tasks: tuple[str, ...]


def env_info(env_cfg: DictConfig) -> EnvInfo:
    """Which tasks the suite has, which are for planner pretraining and which are evaluated."""
    from envs import tasks as suite

    all_tasks = tuple(suite.task_names())
    pre = tuple(suite.task_names(pretraining=True))
    return EnvInfo(all_tasks, tuple(t for t in all_tasks if t not in pre), pre)


@functools.cache
def task_sources(task: str) -> tuple[str, ...]:
    """The source files of one task of the suite (part of the keys of the stages made per task).

    Cached: the pipeline asks at every demos lookup and evaluation, and each answer parses the
    task's modules.
    """
    from envs import tasks as suite

    return tuple(suite.task_sources(task))


def _env_options(env_cfg: DictConfig | None) -> dict[str, Any]:
    return {k: v for k, v in (_plain(env_cfg) or {}).items() if not str(k).startswith("_")}


# The env options a recorded demo depends on: every one but ``max_steps``, the closed loop's action
# budget. Each is passed to demo generation under the generator's name for it.
DEMO_ENV_OPTIONS = {"image_size": "image_size", "render_images": "render",
                    "ticks_per_frame": "ticks_per_frame", "motion_timeout": "motion_timeout"}
EVAL_ONLY_ENV_OPTIONS = ("max_steps",)


def demo_env_options(env_cfg: DictConfig | None) -> dict[str, Any]:
    """The env config's options that shape its recorded demos (the demos' stage key hashes these)."""
    opts = _env_options(env_cfg)
    unknown = sorted(set(opts) - set(DEMO_ENV_OPTIONS) - set(EVAL_ONLY_ENV_OPTIONS))
    if unknown:
        raise ValueError(f"env: option(s) {unknown} reach neither demo generation nor evaluation; "
                         f"known: {sorted([*DEMO_ENV_OPTIONS, *EVAL_ONLY_ENV_OPTIONS])}")
    return {k: v for k, v in opts.items() if k in DEMO_ENV_OPTIONS}


def episodes_for(env_cfg: DictConfig, task: str, split: str, count: int, root: Path) -> list[Path]:
    """Directories of the first ``count`` successful scripted demos of ``task`` in ``split``.

    ``envs.generate`` is resumable and writes each episode atomically under ``root``, so a run
    asking for 3 demos reuses the 1 an earlier run made; seeds come from the split's own range.
    The demos are recorded with the env options the evaluation uses (``demo_env_options``).
    """
    from envs.generate import episode_dir, generate

    options = {DEMO_ENV_OPTIONS[k]: v for k, v in demo_env_options(env_cfg).items()}
    used = generate([task], split, int(count), root, workers=1, progress=progress_enabled(), **options)
    return [episode_dir(root, split, task, seed) for seed in used[task]]


def test_seed(index: int) -> int:
    """The environment seed of evaluation episode ``index`` (the test split's range)."""
    from envs.generate import SPLIT_SEEDS

    seeds = SPLIT_SEEDS["test"]
    if not 0 <= index < len(seeds):
        raise ValueError(f"evaluation seed index {index} outside the test split ({len(seeds)} seeds)")
    return seeds[index]


def make_env(env_cfg: DictConfig, task: str):
    """The gymnasium environment of ``task`` (options from the env config group)."""
    from experiments.config.instantiate import instantiate_component

    if env_cfg is not None and env_cfg.get("_target_"):
        return instantiate_component(env_cfg, "env", task=task)
    from envs.gym_env import make_env as _make

    return _make(task, **_env_options(env_cfg))


def episode_goal(env, info: dict[str, Any]) -> str:
    """The language goal of the episode just reset."""
    return str(info.get("goal") or env.scene_description()["goal"])


def observation_image(obs: dict[str, Any], view: str):
    """The planner's camera image in an env observation."""
    key = f"{view}_rgb"
    if key not in obs:
        raise KeyError(f"observation has no image {key!r}; keys: {sorted(obs)}")
    return obs[key]


def policy_observation(env, obs: dict[str, Any]) -> dict[str, Any]:
    """The env observation in the policy's form: unpadded object state plus the scene description."""
    desc = env.scene_description()
    k, m = len(desc["objects"]), len(desc["articulations"])
    return {
        **obs,
        "objects": desc["objects"],
        "articulations": desc["articulations"],
        "object_positions": obs["object_positions"][:k],
        "object_quaternions": obs["object_quaternions"][:k],
        "articulation_states": obs["articulation_states"][:m],
        "held_object": int(obs["held_object"][0]),
        "gripper_open": float(obs["gripper_open"][0]),
    }


def action_array(action) -> Any:
    """A policy's keyframe action as the env's 8-float action."""
    return action.to_array() if hasattr(action, "to_array") else action


# --- rdd -------------------------------------------------------------------------------------------
def expert_segments(episode) -> list[Segment]:
    """The RLBench keyframe rule's segmentation (the paper segments its training set with it)."""
    from rdd.decomposers.expert import ExpertDecomposer

    return [tuple(int(v) for v in s) for s in ExpertDecomposer().decompose(episode).segments]


def expert_plan(env_cfg: DictConfig, task: str, seed: int, labeler) -> dict[str, Any]:
    """The scripted expert's run of (task, env seed), cut by the keyframe rule and labelled.

    Recorded without images (the labeler reads the privileged record); the instructions are what
    the policy was trained on for the same segments, so they are the oracle planner's answers.
    """
    from envs.expert import run_expert

    opts = {DEMO_ENV_OPTIONS[k]: v for k, v in demo_env_options(env_cfg).items()
            if k in ("ticks_per_frame", "motion_timeout")}
    res = run_expert(task, int(seed), render=False, **opts)
    ep = res.episode
    ep.meta["privileged"] = res.privileged
    segs = expert_segments(ep)
    return {"seed": int(seed), "expert_success": bool(res.success),
            "instructions": [labeler.label(ep, s) for s in segs]}


def build_database(episodes, encoder, views, cache, out: Path) -> None:
    """Build the sub-task database of episodes carrying their labelled segments; save it into ``out``.

    Only each segment's boundary frames are encoded; :func:`calibrate_database` adds what the
    calibrated decomposer needs on top.
    """
    from rdd.database.model import SubtaskDatabase

    db = SubtaskDatabase.build(episodes, None, encoder, views=tuple(views), cache=cache)
    db.save(out / "database")


def merge_databases(parts: Sequence[Path], out: Path) -> None:
    """The saved databases of ``parts`` (stage folders, e.g. one per task) as one, in that order."""
    from rdd.database.model import SubtaskDatabase

    SubtaskDatabase.concat([load_database(p) for p in parts]).save(out / "database")


def calibrate_database(database_dir: Path, episodes, encoder, views, cache, out: Path) -> None:
    """The database in ``database_dir`` plus whole-episode vectors of a sample of its episodes and
    their leave-one-episode-out calibration (``rdd.core.calibrate``), saved into ``out``."""
    from rdd.core.calibrate import calibrate, sample_episodes
    from rdd.encoders.embed import episode_frame_vectors

    db = load_database(database_dir)
    names = [ep.name for ep in episodes]
    if len(set(names)) != len(names):
        raise ValueError("calibration needs unique episode names; the training episodes repeat some")
    keep = set(sample_episodes(names)) if len(names) > 1 else set()
    normalize = bool(db.meta.get("normalize_views", True))
    db.frames = {ep.name: episode_frame_vectors(ep, encoder, views=tuple(views), cache=cache,
                                                normalize=normalize)
                 for ep in episodes if ep.name in keep}
    if db.frames:
        db.meta["calibration"] = calibrate(db)
    db.save(out / "database")


def load_database(path: Path):
    """A saved sub-task database."""
    from rdd.database.model import SubtaskDatabase

    return SubtaskDatabase.load(path / "database")


# --- policy ----------------------------------------------------------------------------------------
POLICY_FILE = "policy.json"


def train_policy(policy: DictConfig | Resolved, episodes, labeler, text_cache: Path, out: Path) -> None:
    """Train the keyframe policy (``policy``: its training factory's node, as the run resolved it) on
    episodes carrying expert segments labelled by ``labeler``.

    The episodes' instructions are the labels the pipeline recorded for these segments; the
    policy's dataset builder labels the same segments with the same labeler, which is checked here.
    """
    from experiments.config.instantiate import component_factory
    from policy.text import shared_embedder

    train = component_factory(policy, "policy")
    eps = list(episodes)
    for ep in eps[:1]:
        got = [labeler.label(ep, tuple(s)) for s in ep.segments]
        if got != list(ep.instructions):
            raise RuntimeError(f"labeler is not deterministic on {ep.name}: {got} != {ep.instructions}")
    policy = train(episodes=eps, labeler=labeler, out_dir=out, embedder=shared_embedder(text_cache),
                   progress=progress_enabled())
    cls = type(policy)
    write_json_atomic(out / POLICY_FILE, {"checkpoint": _relative(policy.checkpoint, out),
                                          "class": f"{cls.__module__}.{cls.__qualname__}"})


def load_policy(policy_cfg: DictConfig, path: Path, text_cache: Path):
    """The trained policy stored in the stage directory ``path``."""
    from hydra.utils import get_object

    info = read_json(path / POLICY_FILE)
    cls = get_object(info["class"])  # the class its training factory returned
    return cls.from_checkpoint(path / info["checkpoint"], text_cache_dir=text_cache)


# --- planner ---------------------------------------------------------------------------------------
# ``planner`` below is the run's learned planner (``planner.llava``: its settings and training steps),
# built once from the config by ``Run.learned_planner``.
def pretrain_planner(planner, episodes, corpus: Sequence[str], out: Path, vocabulary_episodes=(),
                     checkpoint_dir: Path | None = None) -> None:
    """Pretrain the base planner on the pretraining tasks' demos (its tokenizer also sees ``corpus``;
    the slot words of ``vocabulary_episodes`` are saved with it for the finetune's slot swapping;
    training saves its state in ``checkpoint_dir`` to go on after a killed job)."""
    path = planner.pretrain(episodes, out, extra_corpus=list(corpus), vocabulary_episodes=list(vocabulary_episodes),
                            progress=progress_enabled(), checkpoint_dir=checkpoint_dir)
    write_json_atomic(out / PLANNER_FILE, {"base": _relative(path, out)})


def finetune_planner(planner, base_dir: Path, episodes, seed: int, out: Path,
                     checkpoint_dir: Path | None = None, describer_stage: Path | None = None) -> None:
    """LoRA-finetune the base planner on demonstrations carrying their decomposition and labels
    (training saves its state in ``checkpoint_dir`` to go on after a killed job; ``describer_stage``:
    the base stage of the planner's describer, when it names one)."""
    path = planner.finetune(_resolve(base_dir), episodes, out, seed=seed, progress=progress_enabled(),
                            checkpoint_dir=checkpoint_dir, describer=load_describer(planner, describer_stage))
    write_json_atomic(out / PLANNER_FILE, {"adapter": _relative(path, out)})


def _relative(path: Path, root: Path) -> str:
    try:
        return str(Path(path).relative_to(root))
    except ValueError:
        return str(path)  # outside the stage (a real checkpoint): keep its absolute path


def _resolve(stage_dir: Path) -> Path:
    info = read_json(stage_dir / PLANNER_FILE)
    rel = info.get("base") or info.get("adapter")
    p = Path(rel)
    return p if p.is_absolute() else stage_dir / p


def load_describer(planner, describer_stage: Path | None):
    """The loaded base of ``planner``'s describer (``describer_stage``: its base stage), or None."""
    return None if describer_stage is None else planner.describer().load(_resolve(describer_stage))


def load_planner(planner, base_stage: Path, finetune_stage: Path | None, describer=None):
    """The planner: the base, plus the LoRA adapter when finetuned (``describer``: the loaded base,
    which describes its scenes under ``describe_scene``)."""
    adapter = None if finetune_stage is None else _resolve(finetune_stage)
    return planner.load(_resolve(base_stage), adapter, describer=describer)
