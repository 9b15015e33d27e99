"""rdd.registry: one registry of decomposers, encoders and indexes for the CLI and the Hydra configs."""

from __future__ import annotations

import inspect
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rdd import registry
from rdd.decomposers.base import Decomposer
from rdd.encoders.base import Encoder
from rdd.index.base import NearestIndex

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"decomposer": "rdd/decomposers", "encoder": "rdd/encoders", "index": "rdd/index"}


def _registered_in_source(package_dir: str, kind: str) -> set[str]:
    """Names the package's modules register, read from their text (independent of the registry)."""
    text = "\n".join(p.read_text() for p in (ROOT / package_dir).glob("*.py"))
    names = set(re.findall(rf'@register\("{kind}", "(\w+)"\)', text))
    if kind == "encoder":  # the official encoders register through official_builder(SPEC, ...)
        names |= {m for p in (ROOT / package_dir).glob("*.py") if "official_builder(SPEC" in p.read_text()
                  for m in re.findall(r'^    name="(\w+)"', p.read_text(), re.M)}
    return names


@pytest.mark.parametrize("kind", sorted(PACKAGES))
def test_every_registered_component_is_found_and_nothing_else(kind):
    assert set(registry.available(kind)) == _registered_in_source(PACKAGES[kind], kind)


@pytest.mark.parametrize("kind,expected", [
    ("labeler", {"retrieval", "signals", "vlm"}), ("reader", {"rlbench", "lerobot", "native"}),
    ("vlm_backend", {"openai", "transformers"})])
def test_the_other_kinds_are_registered_the_same_way(kind, expected):
    assert set(registry.available(kind)) == expected


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
    assert registry.target("encoder", "clip") == "rdd.encoders.clip.build"
    assert registry.target("encoder", "effnet_lite1") == "rdd.encoders.effnet_lite.build_lite1"


@pytest.mark.parametrize("group,name", [("decomposer", "nope"), ("decomposer", "base"), ("encoder", "cache"),
                                        ("encoder", "../x"), ("planner", "tiny"), ("labeler", "nope")])
def test_unknown_names_fail_naming_what_exists(group, name):
    with pytest.raises(ValueError, match="available|registry has"):
        registry.component(group, name)


def test_cli_offers_exactly_the_registry():
    from rdd.cli.components import decomposer_help, decomposer_names

    assert list(decomposer_names()) == registry.available("decomposer")
    help_text = decomposer_help()
    for name in decomposer_names():
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


PLUGIN = textwrap.dedent('''
    """A decomposer of one's own, outside the package: halves."""
    from rdd.decomposers.base import Decomposer, Decomposition
    from rdd.registry import register


    @register("decomposer", "halves")
    class Halves(Decomposer):
        name = "halves"

        def decompose(self, episode):
            half = max(1, episode.num_frames // 2)
            return Decomposition(segments=[(0, half), (half, episode.num_frames)])
''')


def test_a_new_decomposer_is_one_module(tmp_path, monkeypatch):
    """A module registering a decomposer is all it takes: the registry, the CLI and a config find it."""
    (tmp_path / "my_halves.py").write_text(PLUGIN)
    data = tmp_path / "data"
    from rdd.data.native import save_episode
    from rdd.testing.native_synth import colour_episode

    save_episode(colour_episode("ep0", [4, 3, 3], seed=0), data / "ep0")
    env = {**__import__("os").environ, "RDD_PLUGINS": "my_halves",
           "PYTHONPATH": f"{tmp_path}:{ROOT}"}
    out = tmp_path / "halves.json"
    run = subprocess.run([sys.executable, "-m", "rdd", "decompose", "--format", "native", "--data", str(data),
                          "--decomposer", "halves", "--out", str(out)], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    import json

    (record,) = json.loads(out.read_text())["episodes"]
    assert record["segments"] == [[0, 5], [5, 10]]
    # In this process: the plugin module joins the kind when the registry searches it.
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("RDD_PLUGINS", "my_halves")
    # The registry as it was comes back after the test: the plugin must not stay registered.
    monkeypatch.setattr(registry, "_TABLES", {kind: dict(table) for kind, table in registry._TABLES.items()})
    monkeypatch.setattr(registry, "_SEARCHED", set())
    assert "halves" in registry.available("decomposer")
    assert registry.target("decomposer", "halves") == "my_halves.Halves"


def test_a_plugin_that_cannot_be_imported_is_one_line(tmp_path):
    """``RDD_PLUGINS`` naming a module whose own import fails: the command says which, no traceback."""
    (tmp_path / "broken_plugin.py").write_text("import no_such_module_anywhere\n")
    env = {**__import__("os").environ, "RDD_PLUGINS": "broken_plugin", "PYTHONPATH": f"{tmp_path}:{ROOT}"}
    run = subprocess.run([sys.executable, "-m", "rdd", "decompose", "--help"], env=env, capture_output=True,
                         text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    assert run.stderr.strip().splitlines() == [
        "error: RDD_PLUGINS: cannot import plugin module 'broken_plugin': No module named 'no_such_module_anywhere'"]
