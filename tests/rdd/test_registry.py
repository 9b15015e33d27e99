"""rdd.registry: one registry of decomposers, encoders and indexes for the CLI and the Hydra configs."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from rdd import registry
from rdd.decomposers.base import Decomposer
from rdd.encoders.base import Encoder
from rdd.index.base import NearestIndex

ROOT = Path(__file__).resolve().parents[2]


def _modules(package_dir: str, helpers: set[str]) -> list[str]:
    return sorted(p.stem for p in (ROOT / package_dir).glob("*.py")
                  if not p.stem.startswith("_") and p.stem not in helpers)


def test_every_component_module_is_registered_and_nothing_else():
    assert registry.available("decomposer") == _modules("rdd/decomposers", {"base"})
    assert registry.available("encoder") == _modules("rdd/encoders", {"base", "embed", "cache"})
    assert registry.available("index") == _modules("rdd/index", {"base"})


@pytest.mark.parametrize("group,base", [("decomposer", Decomposer), ("index", NearestIndex)])
def test_class_groups_give_the_module_s_own_subclass(group, base):
    for name in registry.available(group):
        cls = registry.component(group, name)
        assert inspect.isclass(cls) and issubclass(cls, base)
        assert cls.__module__ == f"rdd.{'decomposers' if group == 'decomposer' else 'index'}.{name}"
        assert registry.name_of(group, registry.target(group, name)) == name


def test_encoders_are_their_module_s_build():
    enc = registry.component("encoder", "pixels")(size=4)
    assert isinstance(enc, Encoder) and enc.name == "pixels"
    assert registry.target("encoder", "pixels") == "rdd.encoders.pixels.build"


@pytest.mark.parametrize("group,name", [("decomposer", "nope"), ("decomposer", "base"), ("encoder", "cache"),
                                        ("encoder", "../x"), ("planner", "tiny")])
def test_unknown_names_fail_naming_what_exists(group, name):
    with pytest.raises(ValueError, match="available|registry has"):
        registry.component(group, name)


def test_cli_offers_exactly_the_registry():
    from rdd.cli.components import DECOMPOSERS, decomposer_help

    assert list(DECOMPOSERS) == registry.available("decomposer")
    help_text = decomposer_help()
    for name in DECOMPOSERS:
        assert f"  {name}: " in help_text
