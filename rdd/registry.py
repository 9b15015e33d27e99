"""The one registry of everything chosen by name, and the one way to build it, for the CLI, the server
and the harness.

Every *kind* of component (decomposer, encoder, index, labeler, reader, VLM backend; the harness adds
task) is one table, filled by one mechanism: the component says its name where it is defined::

    @register("decomposer", "uvd")
    class UVDDecomposer(Decomposer): ...

A kind's table is filled by importing every public module of its packages (:data:`KINDS`), so adding a
component is one module in that package (plus, for the harness, one ``conf/<group>/<name>.yaml`` whose
``_target_`` is :func:`target` of it); a module outside the package joins through the environment
variable ``RDD_PLUGINS`` (comma-separated module names, imported with the kinds). ``python -m rdd``
builds ``--decomposer NAME`` / ``--encoder NAME`` through :func:`component`, and a Hydra option's
``_target_`` names the same object, so the two cannot drift. An unknown name lists the known ones.

A component is called with its options (keyword arguments: the CLI's ``--option``, a config's keys)
and the *runtime objects* it takes (:data:`RUNTIME_OBJECTS`): what exists only once a run has made
it, each under one name, passed to exactly the components with a parameter of that name
(:func:`construct`; the harness's ``experiments.config.instantiate`` and the CLI both call it).
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Kind:
    """Where a kind's components are defined and what each must be."""

    packages: tuple[str, ...]  # every public module of these is imported to find the components
    base: str | None = None  # "module:Class" each component subclasses (None: any callable or object)
    factory: bool = False  # components are ``build(**options)`` factories, not classes


KINDS: dict[str, Kind] = {
    "decomposer": Kind(("rdd.decomposers",), "rdd.decomposers.base:Decomposer"),
    "encoder": Kind(("rdd.encoders",), "rdd.encoders.base:Encoder", factory=True),
    "index": Kind(("rdd.index",), "rdd.index.base:NearestIndex"),
    "labeler": Kind(("rdd.labelers",)),
    "reader": Kind(("rdd.data",)),
    "vlm_backend": Kind(("rdd.labelers.vlm_backends",)),
}
PLUGINS_ENV = "RDD_PLUGINS"
_TABLES: dict[str, dict[str, Any]] = {}
_SEARCHED: set[str] = set()
_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
# What a run makes at run time and hands to the components that take it, one name each.
RUNTIME_OBJECTS: dict[str, str] = {
    "database": "the sub-task database (of the training episodes)",
    "encoder": "the visual encoder",
    "cache": "the on-disk embedding cache",
}


def define_kind(kind: str, packages: Sequence[str], base: str | None = None, factory: bool = False) -> None:
    """Add a kind whose components live above the library (the harness's tasks)."""
    KINDS[kind] = Kind(tuple(packages), base, factory)
    _SEARCHED.discard(kind)


def register(kind: str, name: str) -> Callable[[T], T]:
    """Decorator: the class or factory it decorates is the component ``name`` of ``kind``."""
    if not _NAME_RE.match(name):
        raise ValueError(f"{kind} {name!r} is not a component name (lower case, digits, underscores)")

    def add(obj: T) -> T:
        table = _TABLES.setdefault(kind, {})
        old = table.get(name)
        if old is not None and _dotted(old) != _dotted(obj):
            raise ValueError(f"{kind} {name!r} is registered twice: {_dotted(old)} and {_dotted(obj)}")
        table[name] = obj
        return obj

    return add


def _dotted(obj: Any) -> str:
    return f"{obj.__module__}.{obj.__qualname__}"


def _kind(kind: str) -> Kind:
    if kind not in KINDS:
        raise ValueError(f"unknown component kind {kind!r}; the registry has {sorted(KINDS)}")
    return KINDS[kind]


def _search(kind: str) -> dict[str, Any]:
    """The table of ``kind``, after importing every public module of its packages and the plugins."""
    if kind not in _SEARCHED:
        for package in _kind(kind).packages:
            module = importlib.import_module(package)
            for info in pkgutil.walk_packages(getattr(module, "__path__", []), package + "."):
                if not any(part.startswith("_") for part in info.name.split(".")):
                    importlib.import_module(info.name)
        for plugin in filter(None, (p.strip() for p in os.environ.get(PLUGINS_ENV, "").split(","))):
            try:
                importlib.import_module(plugin)
            except ImportError as exc:
                raise ImportError(f"{PLUGINS_ENV}: cannot import plugin module {plugin!r}: {exc}") from exc
        _SEARCHED.add(kind)
    return _TABLES.setdefault(kind, {})


def entries(kind: str) -> dict[str, Any]:
    """The components of ``kind``, name -> class or factory, in the order they were registered."""
    return dict(_search(kind))


def available(kind: str) -> list[str]:
    """Names of the components of ``kind``, sorted."""
    return sorted(_search(kind))


def component(kind: str, name: str) -> Any:
    """The class or factory registered as ``name`` of ``kind``; an unknown name lists the known ones."""
    table = _search(kind)
    if not isinstance(name, str) or name not in table:
        raise ValueError(f"unknown {kind} {name!r}; available: {sorted(table)}")
    return table[name]


def target(kind: str, name: str) -> str:
    """The dotted path of :func:`component` (what a Hydra config's ``_target_`` names)."""
    return _dotted(component(kind, name))


def name_of(kind: str, dotted: str) -> str | None:
    """The registry name whose :func:`target` is ``dotted`` (None when it is not a registered one)."""
    if kind not in KINDS:
        return None
    return next((n for n, obj in _search(kind).items() if _dotted(obj) == dotted), None)


def build(kind: str, name: str, /, **options: Any) -> Any:
    """The component ``name`` of ``kind`` built with ``options`` (it takes no runtime object)."""
    built = construct(component(kind, name), {}, target(kind, name), **options)
    base = _kind(kind).base
    if base is not None:
        module, _, cls = base.partition(":")
        expected = getattr(importlib.import_module(module), cls)
        if not isinstance(built, expected):
            raise TypeError(f"{target(kind, name)} returned {type(built).__name__}, not {expected.__name__}")
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
