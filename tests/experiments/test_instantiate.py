"""Components get exactly the runtime objects they name (database, encoder, cache), nothing else."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf, open_dict

import experiments.config.schemas  # noqa: F401  (registers base_config)
from experiments.config.instantiate import check_call, instantiate_component, resolve, runtime_names
from experiments.config.validate import ConfigError
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.decomposers.uniform import UniformDecomposer

CONF = Path(__file__).resolve().parents[2] / "conf"


class EmbeddingCacheDecomposer(Decomposer):
    """Asks for the embedding cache under a name the run does not use (the old alias)."""

    def __init__(self, embedding_cache, n_segments: int = 2):
        self.inner = UniformDecomposer(n_segments)

    def decompose(self, episode) -> Decomposition:
        return self.inner.decompose(episode)


class IndexLabeler:
    """Asks for a retrieval index as if it were a runtime object (it is a config option)."""

    def __init__(self, database, nearest_index):
        self.database = database

    def label(self, episode, segment) -> str:
        return "x"


def _node(cls: type, **options) -> OmegaConf:
    return OmegaConf.create({"_target_": f"{cls.__module__}.{cls.__qualname__}", **options})


@pytest.fixture(scope="module")
def encoder():
    from rdd.encoders import load_encoder

    return load_encoder("pixels", size=4)


def test_runtime_objects_go_only_where_taken(encoder):
    uniform = _node(UniformDecomposer, n_segments=3)
    assert runtime_names(uniform, "decomposer") == ()
    assert instantiate_component(uniform, "decomposer").n_segments == 3
    uvd = OmegaConf.create({"_target_": "rdd.decomposers.uvd.UVDDecomposer", "_partial_": True,
                            "min_interval": 5})
    assert runtime_names(uvd, "decomposer") == ("encoder", "cache")
    dec = instantiate_component(uvd, "decomposer", {"encoder": encoder, "cache": None})
    assert dec.encoder is encoder and dec.min_interval == 5
    with pytest.raises(TypeError, match=r"takes the runtime objects \['encoder', 'cache'\]"):
        instantiate_component(uvd, "decomposer", {"encoder": encoder})  # one missing
    with pytest.raises(TypeError, match="passed"):
        instantiate_component(uniform, "decomposer", {"encoder": encoder})  # one it does not take


def test_rdd_gets_the_index_group_s_choice_from_its_config(encoder):
    """The index is composed (``index: ${index}``), not passed: abl_backend's sweep reaches RDD."""
    from rdd.database.model import SubtaskDatabase

    rng = np.random.default_rng(0)
    db = SubtaskDatabase.from_arrays(rng.standard_normal((6, 2 * encoder.dim)),
                                     rng.standard_normal((6, 2 * encoder.dim)), rng.integers(3, 9, 6),
                                     [f"s{i}" for i in range(6)],
                                     meta={"encoder": encoder.name, "weights_id": encoder.weights_id,
                                           "views": ["front", "wrist"]})
    for index, cls in (("exact", "ExactIndex"), ("annoy", "AnnoyIndex")):
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            cfg = compose(config_name="config", overrides=["decomposer=rdd", f"index={index}",
                                                           "paths.cache_dir=/tmp/unused"])
        takes = runtime_names(cfg.decomposer, "decomposer")
        assert takes == ("database", "encoder", "cache")
        dec = instantiate_component(cfg.decomposer, "decomposer",
                                    {"database": db, "encoder": encoder, "cache": None})
        assert type(dec.index).__name__ == cls


def test_runtime_object_set_in_the_config_is_refused():
    uvd = OmegaConf.create({"_target_": "rdd.decomposers.uvd.UVDDecomposer", "cache": "/tmp/x"})
    with pytest.raises(ConfigError, match=r"decomposer.cache: `cache` is a runtime object"):
        runtime_names(uvd, "decomposer")


def test_a_component_s_signature_is_read_once_for_both_checks():
    """resolve reads the target once: the runtime objects it takes and the parameters it cannot do without."""
    component = resolve(_node(IndexLabeler), "labeler")
    assert component.runtime == ("database",) and component.required == ("database", "nearest_index")
    check_call(component, ["database", "nearest_index"])
    with pytest.raises(ConfigError, match=r"labeler \(.*IndexLabeler\): parameter 'nearest_index' is not set"):
        check_call(component, component.runtime)
    assert resolve(component, "labeler") is component


@pytest.mark.parametrize("group,cls,param", [
    ("decomposer", EmbeddingCacheDecomposer, "embedding_cache"),
    ("labeler", IndexLabeler, "nearest_index"),
])
def test_unknown_runtime_name_fails_before_any_stage(tmp_path: Path, group: str, cls: type, param: str):
    """A decomposer or labeler asking for an object under a name the run does not pass: one clear error."""
    pytest.importorskip("pybullet")
    from experiments.run.pipeline import run

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            "experiment=smoke", "decomposer=uniform", "labeler=privileged", f"paths.cache_dir={tmp_path / 'cache'}"])
    with open_dict(cfg):
        cfg[group] = _node(cls)
        cfg.output_dir = str(tmp_path / "out")
    with pytest.raises(ConfigError) as err:
        run(cfg)
    msg = str(err.value)
    assert f"{group} ({cls.__module__}.{cls.__qualname__})" in msg and repr(param) in msg, msg
    assert "database, encoder, cache" in msg
    assert not any((tmp_path / "cache").glob("*/*")), "no stage may run before the check"


@pytest.mark.parametrize("option", sorted(p.stem for p in (CONF / "decomposer").glob("*.yaml")))
def test_decomposer_views_are_the_run_s(option: str):
    """A decomposer embeds the run's views (top-level ``views``), never a copy of its own that could drift."""
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"decomposer={option}", "views=[wrist]",
                                                       "paths.cache_dir=/tmp/unused"])
    if "views" in cfg.decomposer:
        assert list(cfg.decomposer.views) == ["wrist"], option
