"""The one registry of swappable rdd components, read by the CLI and by the harness's Hydra configs.

A component is found by convention, with no central table: the decomposer ``NAME`` is the
:class:`~rdd.decomposers.base.Decomposer` subclass defined in module ``rdd.decomposers.NAME``, the
encoder ``NAME`` is the ``build(**options)`` factory of module ``rdd.encoders.NAME``, the index
``NAME`` is the :class:`~rdd.index.base.NearestIndex` subclass of ``rdd.index.NAME``. Adding one is
one module (plus, for the harness, one ``conf/<group>/<option>.yaml`` whose ``_target_`` is
:func:`target` of it). ``python -m rdd`` builds ``--decomposer NAME`` / ``--encoder NAME`` through
:func:`component`, and a Hydra option's ``_target_`` names the same object, so the two cannot drift.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from typing import Any

# group -> (package, what the module contributes: "class" = the subclass of ``base`` it defines,
# "build" = its build() factory)
GROUPS: dict[str, tuple[str, str, str]] = {
    "decomposer": ("rdd.decomposers", "class", "rdd.decomposers.base:Decomposer"),
    "encoder": ("rdd.encoders", "build", "rdd.encoders.base:Encoder"),
    "index": ("rdd.index", "class", "rdd.index.base:NearestIndex"),
}
# Modules of those packages that hold shared code, not a component.
_NOT_COMPONENTS = {"base", "embed", "cache"}
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")


def _group(group: str) -> tuple[str, str, type]:
    if group not in GROUPS:
        raise ValueError(f"unknown component group {group!r}; the registry has {sorted(GROUPS)}")
    package, kind, base = GROUPS[group]
    module, _, cls = base.partition(":")
    return package, kind, getattr(importlib.import_module(module), cls)


def available(group: str) -> list[str]:
    """Names of the components of ``group`` (modules of its package, helpers excluded)."""
    package, _, _ = _group(group)
    pkg = importlib.import_module(package)
    return sorted(info.name for info in pkgutil.iter_modules(pkg.__path__)
                  if not info.name.startswith("_") and not info.ispkg and info.name not in _NOT_COMPONENTS)


def component(group: str, name: str) -> Any:
    """The class (decomposer, index) or factory (encoder) registered as ``name`` in ``group``."""
    package, kind, base = _group(group)
    if not isinstance(name, str) or not _NAME_RE.match(name) or name in _NOT_COMPONENTS:
        raise ValueError(f"{group} {name!r} is not a component name; available: {available(group)}")
    if name not in available(group):
        raise ValueError(f"unknown {group} {name!r}; available: {available(group)}")
    module = importlib.import_module(f"{package}.{name}")
    if kind == "build":
        build = getattr(module, "build", None)
        if not callable(build):
            raise ValueError(f"module {package}.{name} has no build(); available: {available(group)}")
        return build
    found = [obj for obj in vars(module).values()
             if inspect.isclass(obj) and issubclass(obj, base) and obj is not base
             and obj.__module__ == module.__name__ and not inspect.isabstract(obj)]
    if len(found) != 1:
        raise ValueError(f"module {package}.{name} must define exactly one {base.__name__} subclass, "
                         f"found {[c.__name__ for c in found]}")
    return found[0]


def target(group: str, name: str) -> str:
    """The dotted path of :func:`component` (what a Hydra config's ``_target_`` names)."""
    obj = component(group, name)
    if GROUPS[group][1] == "build":
        return f"{GROUPS[group][0]}.{name}.build"  # the module's factory (it may be a partial)
    return f"{obj.__module__}.{obj.__qualname__}"


def name_of(group: str, dotted: str) -> str | None:
    """The registry name whose :func:`target` is ``dotted`` (None when it is not a registered one)."""
    package = GROUPS[group][0] if group in GROUPS else None
    if package is None or not dotted.startswith(package + "."):
        return None
    name = dotted[len(package) + 1:].split(".", 1)[0]
    try:
        return name if target(group, name) == dotted else None
    except (ValueError, ImportError):
        return None


def build_from_module(package: str, name: str, base: type, available: list[str], options: dict[str, Any]) -> Any:
    """Import ``package.name``, call its ``build(**options)`` and check the result is a ``base``."""
    module = importlib.import_module(f"{package}.{name}")
    build = getattr(module, "build", None)
    if not callable(build):
        raise ValueError(f"module {package}.{name} has no build(); available: {available}")
    built = build(**options)
    if not isinstance(built, base):
        raise TypeError(f"{package}.{name}.build returned {type(built).__name__}, not {base.__name__}")
    return built
