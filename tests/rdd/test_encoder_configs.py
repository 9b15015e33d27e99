"""conf/encoder/*.yaml: one per encoder module, options the builder accepts, instantiable by Hydra."""

import inspect
from pathlib import Path

import pytest

from rdd.encoders import available_encoders

CONF = Path(__file__).resolve().parents[2] / "conf" / "encoder"


def _yaml(name):
    omegaconf = pytest.importorskip("omegaconf")
    return omegaconf.OmegaConf.load(CONF / f"{name}.yaml")


def test_every_encoder_module_has_a_config_and_back():
    stems = sorted(p.stem for p in CONF.glob("*.yaml"))
    assert stems == available_encoders()


@pytest.mark.parametrize("name", available_encoders())
def test_config_options_are_builder_arguments(name):
    from rdd.registry import component, target

    cfg = _yaml(name)
    assert cfg["_target_"] == target("encoder", name)
    params = inspect.signature(component("encoder", name)).parameters
    unknown = set(cfg) - {"_target_"} - set(params)
    assert not unknown, f"conf/encoder/{name}.yaml has options build() does not take: {unknown}"


@pytest.mark.parametrize("name,overrides", [("pixels", {}), ("r3m", {"random_weights": True})])
def test_hydra_instantiates_config(name, overrides):
    hydra_utils = pytest.importorskip("hydra.utils")
    cfg = _yaml(name)
    for k, v in overrides.items():
        cfg[k] = v
    enc = hydra_utils.instantiate(cfg)
    assert enc.name == name and enc.dim > 0
