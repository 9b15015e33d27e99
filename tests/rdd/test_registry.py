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


def test_one_constructor_with_exactly_the_runtime_objects_taken():
    """What the CLI and the harness both call: options checked by name, runtime objects by parameter."""
    uvd = registry.component("decomposer", "uvd")
    assert registry.runtime_names(uvd) == ("encoder", "cache")
    with pytest.raises(TypeError, match=r"takes the runtime objects \['encoder', 'cache'\]"):
        registry.construct(uvd, {"encoder": None}, "decomposer uvd")
    with pytest.raises(ValueError, match=r"decomposer uvd: unknown option\(s\) \['bogus'\]"):
        registry.check_option_names("decomposer", uvd, {"bogus": 1})
    assert registry.construct(uvd, {"encoder": None, "cache": None}, "decomposer uvd", min_interval=5).min_interval == 5
    assert type(registry.build("index", "exact")) is registry.component("index", "exact")
