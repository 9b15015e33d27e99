"""The one registry of swappable rdd components and the one way to build them, for the CLI and the harness.

A component is found by convention, with no central table: the decomposer ``NAME`` is the
:class:`~rdd.decomposers.base.Decomposer` subclass defined in module ``rdd.decomposers.NAME``, the
encoder ``NAME`` is the ``build(**options)`` factory of module ``rdd.encoders.NAME``, the index
``NAME`` is the :class:`~rdd.index.base.NearestIndex` subclass of ``rdd.index.NAME``. Adding one is
one module (plus, for the harness, one ``conf/<group>/<option>.yaml`` whose ``_target_`` is
:func:`target` of it). ``python -m rdd`` builds ``--decomposer NAME`` / ``--encoder NAME`` through
:func:`component`, and a Hydra option's ``_target_`` names the same object, so the two cannot drift.

A component is called with its options (keyword arguments: the CLI's ``--option``, a config's keys)
and the *runtime objects* it takes (:data:`RUNTIME_OBJECTS`): what exists only once a run has made
it, each under one name, passed to exactly the components with a parameter of that name
(:func:`construct`; the harness's ``experiments.config.instantiate`` and the CLI both call it).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from collections.abc import Iterable, Mapping, Sequence
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
# What a run makes at run time and hands to the components that take it, one name each.
RUNTIME_OBJECTS: dict[str, str] = {
    "database": "the sub-task database (of the training episodes)",
    "encoder": "the visual encoder",
    "cache": "the on-disk embedding cache",
}


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


def build(group: str, name: str, **options: Any) -> Any:
    """The component ``name`` of ``group`` built with ``options`` (it takes no runtime object)."""
    built = construct(component(group, name), {}, target(group, name), **options)
    base = _group(group)[2]
    if not isinstance(built, base):
        raise TypeError(f"{target(group, name)} returned {type(built).__name__}, not {base.__name__}")
    return built


def parameters(fn: Any) -> dict[str, inspect.Parameter]:
    """The parameters a caller may pass ``fn`` by keyword (a class: its constructor's)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):  # a builtin without a signature: nothing to check against
        return {}
    return {n: p for n, p in params.items()
            if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)}


def runtime_names(fn: Any) -> tuple[str, ...]:
    """The runtime objects ``fn`` takes: its parameters named in :data:`RUNTIME_OBJECTS`."""
    params = parameters(fn)
    return tuple(name for name in RUNTIME_OBJECTS if name in params)


def unset_parameters(fn: Any, given: Iterable[str]) -> list[str]:
    """Parameters of ``fn`` without a default that ``given`` (the names a caller will pass) leaves out."""
    given = set(given)
    return [name for name, p in parameters(fn).items()
            if p.default is inspect.Parameter.empty and name not in given]


def check_option_names(group: str, fn: Any, options: Mapping[str, Any], reserved: Sequence[str] = ()) -> None:
    """Reject keys of ``options`` that ``fn`` does not take (``reserved``: set by the caller, not an option).

    A ``fn`` with ``**kwargs`` passes the other keys on; it checks them itself (e.g. the VLM
    decomposer's backend options).
    """
    try:
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(fn).parameters.values()):
            return
    except (TypeError, ValueError):
        pass
    accepted = [p for p in parameters(fn) if p not in reserved]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        owner = getattr(fn, "name", getattr(fn, "__name__", str(fn)))
        raise ValueError(f"{group} {owner}: unknown option(s) {unknown}; accepted: {', '.join(accepted)}")


def construct(fn: Any, runtime: Mapping[str, Any], owner: str, /, **options: Any) -> Any:
    """Call the component ``fn`` with ``options`` and exactly the runtime objects it takes.

    ``runtime`` must hold every runtime object ``fn`` takes (:func:`runtime_names`) and no other;
    ``owner`` names the component in that error. The three are positional-only, so an option may
    share their names (the encoders' ``runtime`` option).
    """
    wanted = runtime_names(fn)
    if set(runtime) != set(wanted):
        raise TypeError(f"{owner} takes the runtime objects {list(wanted)}, but the caller passed {sorted(runtime)}")
    return fn(**runtime, **options)
