"""Every option of every config group composes and instantiates; typos fail at compose time."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

import experiments.config.schemas  # noqa: F401  (registers base_config)
from experiments.config.instantiate import RUNTIME_OBJECTS, instantiate_component, runtime_names

CONF = Path(__file__).resolve().parents[2] / "conf"
GROUPS = ("env", "encoder", "index", "decomposer", "labeler", "policy", "planner")


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


def _compose(overrides: list[str], hydra: bool = False):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides, return_hydra_config=hydra)


def test_every_group_has_options():
    for group in (*GROUPS, "experiment"):
        assert _options(group), f"conf/{group}/ has no option"


@pytest.fixture(scope="module")
def runtime():
    """The run's runtime objects, each under its one name (a tiny database, the pixels encoder)."""
    from rdd.database.model import SubtaskDatabase
    from rdd.encoders import load_encoder

    enc = load_encoder("pixels", size=4)
    rng = np.random.default_rng(0)
    dim = 2 * enc.dim
    begin, end = rng.standard_normal((8, dim)), rng.standard_normal((8, dim))
    db = SubtaskDatabase.from_arrays(begin, end, rng.integers(3, 9, 8), [f"step {i}" for i in range(8)],
                                     meta={"encoder": enc.name, "weights_id": enc.weights_id,
                                           "views": ["front", "wrist"],
                                           "calibration": {"chosen": {"alpha": 0.5, "min_len": 2,
                                                                      "max_len": None}}})
    return {"encoder": enc, "database": db, "cache": None}


# What the pipeline's call sites pass besides runtime objects (experiments/run/components.py, pipeline.py).
CALL_SITE = {"env": {"task": "open_drawer"},
             "planner": {"plans": {"open_drawer": {0: ["reach for the top drawer handle"]}}}}


@pytest.mark.parametrize("group,option", [(g, o) for g in GROUPS for o in _options(g)])
def test_option_composes_and_instantiates(group: str, option: str, runtime):
    from experiments.config.validate import target_callable, validate_config
    from experiments.run.graph import with_row_planner

    cfg = _compose([f"{group}={option}", "paths.cache_dir=/tmp/unused"])
    validate_config(cfg)  # every key of the option is a parameter of its target, of its type
    cfg = with_row_planner(cfg)  # then the row's own planner in place, as the pipeline does
    node = cfg[group]
    if not node or not node.get("_target_"):
        assert group == "decomposer" and option in ("none", "other_tasks")  # no finetuning
        return
    takes = runtime_names(node, group)
    assert set(takes) <= set(RUNTIME_OBJECTS)
    if group not in ("decomposer", "labeler"):
        assert takes == (), f"only decomposers and labelers get runtime objects, {group}={option} asks {takes}"
    if group == "policy":
        # a training factory: the pipeline passes the episodes, labeler and folder at the call site
        from experiments.config.instantiate import component_factory

        factory = component_factory(node, group)
        assert {"episodes", "labeler", "out_dir"} <= set(inspect.signature(factory).parameters)
        return
    target = target_callable(node, group)
    call = CALL_SITE.get(group, {}) if not getattr(target, "learned", False) else {}
    try:
        obj = instantiate_component(node, group, {n: runtime[n] for n in takes}, **call)
    except FileNotFoundError as exc:
        # Components whose weights are not on this machine say where to put them.
        msg = str(exc)
        assert any(w in msg for w in ("checkpoint", "weights", "RDD_WEIGHTS_DIR", "path")), msg
        return
    assert obj is not None
    for name in takes:  # the runtime object reached the component as given
        assert getattr(obj, name) is runtime[name]


@pytest.mark.parametrize("option", ["tiny_llava", "tiny_llava_next", "llava_next_8b"])
def test_learned_planner_targets_build_the_model_their_file_names(option: str):
    """The class a planner option names fixes the model; its settings (and so the base key) are the YAML's."""
    from planner.config import PlannerConfig

    node = _compose([f"planner={option}", "paths.cache_dir=/tmp/unused"]).planner
    planner = instantiate_component(node, "planner")
    assert planner.learned and planner.config.kind == option
    options = {k: v for k, v in OmegaConf.to_container(node, resolve=True).items() if k != "_target_"}
    expected = PlannerConfig.from_dict({"kind": option, **options})
    assert planner.base_spec() == {"model": expected.model_dict()}
    assert planner.config.to_dict() == expected.to_dict()


@pytest.mark.parametrize("experiment", _options("experiment"))
def test_experiment_composes(experiment: str):
    cfg = _compose([f"experiment={experiment}", "paths.cache_dir=/tmp/unused"], hydra=True)
    assert cfg.hydra.runtime.choices.experiment == experiment
    OmegaConf.to_container(cfg, resolve=False)  # every node is well formed
    from experiments.config.validate import validate_config

    validate_config(cfg)  # and every key is known and of its type


@pytest.mark.parametrize("launcher", ["local", "slurm", "slurm_local", "ray", "joblib"])
def test_launchers_compose(launcher: str):
    if launcher.startswith("slurm"):  # their schema comes with the plugin
        pytest.importorskip("hydra_plugins.hydra_submitit_launcher",
                            reason="needs the cluster extra: pip install -c constraints.txt -e '.[cluster]'")
    cfg = _compose([f"hydra/launcher={launcher}"], hydra=True)
    assert "_target_" in cfg.hydra.launcher
    if launcher == "local":
        assert cfg.hydra.launcher.n_jobs == 2
    if launcher == "slurm":  # the keys a lab sets are typed: a misspelt one fails at compose time
        cfg = _compose(["hydra/launcher=slurm", "hydra.launcher.partition=gpu",
                        "hydra.launcher.cpus_per_task=8"], hydra=True)
        assert (cfg.hydra.launcher.partition, cfg.hydra.launcher.cpus_per_task) == ("gpu", 8)
        with pytest.raises(ConfigCompositionException):
            _compose(["hydra/launcher=slurm", "hydra.launcher.partiton=gpu"], hydra=True)


@pytest.mark.parametrize("override", [
    "sed=1",                           # misspelt top-level key
    "eval.episodes_per_task=many",     # wrong type
    "mode=trian",                      # not a mode
    "data.train_episodes=3",           # misspelt nested key
    "decomposer=rddd",                 # no such option
    "decomposer.alpah=2",              # misspelt component option
])
def test_typos_fail_at_compose_time(override: str):
    with pytest.raises(ConfigCompositionException):
        _compose([override])


@pytest.mark.parametrize("override,named", [
    ("decomposer.alpha=abc", "decomposer.alpha: expected float, got 'abc'"),
    ("+alpha=abc", "alpha: unknown key"),                    # Hydra's own hint for a new key
    ("+data.foo=1", "data.foo: unknown key"),
    ("+decomposer.alpah=2", "decomposer.alpah: unknown option"),
    ("planner.finetune.epochs=many", "planner.finetune.epochs: expected int, got 'many'"),
    ("+planner.lora.rank=4", "planner.lora.rank: unknown key"),
    ("policy.net.hidden=1.5", "policy.net.hidden: expected int, got 1.5"),
    ("policy.train.lr=fast", "policy.train.lr: expected float"),
    ("env.image_size=big", "env.image_size: expected int, got 'big'"),
    ("index.prune=maybe", "index.prune: expected bool, got 'maybe'"),
    ("decomposer.views=[front,2]", "decomposer.views: expected"),
])
def test_mistyped_or_unknown_keys_fail_before_any_stage(override: str, named: str):
    from experiments.config.validate import ConfigError, validate_config

    cfg = _compose([override, "paths.cache_dir=/tmp/unused"])
    with pytest.raises(ConfigError) as err:
        validate_config(cfg)
    assert named in str(err.value)




def test_default_is_the_quick_rdd_effnet_run():
    cfg = _compose(["paths.cache_dir=/tmp/unused"], hydra=True)
    choices = cfg.hydra.runtime.choices
    assert (choices.decomposer, choices.encoder, choices.experiment) == ("rdd", "effnet_lite0", "quick")
    assert cfg.planner._target_ == "planner.llava.TinyLlava"  # the paper tables' SmolLM2 pair is not quick
    assert cfg.wandb.mode == "offline"


@pytest.mark.parametrize("experiment", ["table_main", "planner_eval", "necessity", "abl_alpha"])
def test_the_paper_tables_plan_with_smollm2_on_the_tiny_describer_s_captions(experiment: str):
    """The shared scale picks the describe-then-plan pair; `planner=NAME` still overrides it."""
    cfg = _compose([f"experiment={experiment}", "paths.cache_dir=/tmp/unused"], hydra=True)
    assert cfg.hydra.runtime.choices.planner == "smollm2_llava_describer"
    assert cfg.planner._target_ == "planner.llava.SmolLlava" and cfg.planner.describe_scene
    assert cfg.planner.describer._target_ == "planner.llava.TinyLlava" and cfg.planner.describer.describe_scene
    picked = _compose([f"experiment={experiment}", "planner=tiny_llava", "paths.cache_dir=/tmp/unused"])
    assert picked.planner._target_ == "planner.llava.TinyLlava" and "describer" not in picked.planner


@pytest.mark.parametrize("group", ["decomposer", "encoder", "index"])
def test_hydra_options_name_the_rdd_registry_s_components(group: str):
    """conf/<group>/*.yaml target the very objects `python -m rdd` builds by name (one registry)."""
    from rdd.registry import available, name_of

    named = set()
    for option in _options(group):
        node = OmegaConf.load(CONF / group / f"{option}.yaml")
        if "_target_" not in node:
            assert (group, option) in (("decomposer", "none"), ("decomposer", "other_tasks"))  # nothing decomposed
            continue
        # A classmethod factory (RDDDecomposer.calibrated) builds its registered class.
        name = name_of(group, node._target_) or name_of(group, node._target_.rpartition(".")[0])
        assert name is not None, f"conf/{group}/{option}.yaml: {node._target_} is not in rdd.registry"
        named.add(name)
    assert named == set(available(group))  # and every registered component has an option


def test_the_w_o_finetune_row_evaluates_a_vanilla_planner_and_the_necessity_row_the_base():
    """decomposer=none swaps in a pretrained language model never tuned on an instruction, whatever
    planner the run names; decomposer=other_tasks keeps the run's own base planner."""
    from experiments.run.graph import finetunes, with_row_planner
    from planner.config import PlannerConfig
    from planner.llava import SmolLlava

    vanilla = with_row_planner(_compose(["decomposer=none", "planner=tiny_llava", "paths.cache_dir=/tmp/unused"]))
    assert vanilla.planner._target_ == "planner.llava.SmolLlava"
    options = OmegaConf.to_container(vanilla.planner)
    cfg = SmolLlava(**{k: v for k, v in options.items() if k != "_target_"}).config
    assert cfg.kind == "smollm2_llava" and not cfg.instruction_tuning and cfg.pretrain.caption_frame_stride > 0
    assert "planner" not in vanilla.decomposer and not finetunes(vanilla)
    necessity = with_row_planner(_compose(["decomposer=other_tasks", "planner=tiny_llava",
                                           "paths.cache_dir=/tmp/unused"]))
    assert necessity.planner._target_ == "planner.llava.TinyLlava" and not finetunes(necessity)
    oracle = with_row_planner(_compose(["experiment=oracle", "paths.cache_dir=/tmp/unused"]))
    assert oracle.planner._target_.startswith("planner.oracle")  # no learned planner: its plans stay
    with pytest.raises(ValueError, match="instruction_tuning false needs a pretrained language model"):
        PlannerConfig(kind="tiny_llava", instruction_tuning=False)
    with pytest.raises(ValueError, match="caption_frame_stride"):
        PlannerConfig(kind="smollm2_llava", vision_tower="effnet_lite0_mid", image_size=224, patch_size=32,
                      instruction_tuning=False)
