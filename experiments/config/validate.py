"""Check a composed config before any stage runs: every key known, every value of the expected type
and within its range.

Hydra's typed schema (``experiments.config.schemas.RunConfig``) covers the run's own keys but accepts keys
added with ``+`` and cannot see inside the component groups, whose options are ``_target_`` nodes.
Here each key is checked against what consumes it: the schema's fields for the run's keys, and the
signature of the ``_target_`` (its parameters and type hints; a dataclass-typed parameter given as a
mapping is checked field by field) for component nodes. The first problem is reported with its
dotted key, the expected type and the value given (``decomposer.alpha: expected float, got 'abc'``).
Numbers are checked against the ranges their dataclass fields declare (``experiments.config.schemas.ranged``:
``eval.episodes_per_task: expected >= 1 and <= 10000, got -1``), a run's seeds against the test
split (:func:`check_relations`), a dataclass-typed value is built once here so its own checks
(``__post_init__``) fail now, not when a stage builds it, and a component that declares its options'
ranges (``check_options``, ``rdd.checks``: decomposers, indexes, the env) has them checked now
(``decomposer.alpha: decomposer rdd: option alpha must be a finite number ..., got nan``).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
import math
import os
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from rdd.errors import InputError

HYDRA_KEYS = {"_target_", "_partial_", "_recursive_", "_convert_", "_args_"}


class ConfigError(InputError):
    """A key of the composed config is unknown or its value has the wrong type."""


def target_callable(node: DictConfig, group: str) -> Callable[..., Any]:
    """The callable named by ``node._target_``, with an error naming the group when it is wrong."""
    from hydra.utils import get_object

    target = node.get("_target_") if isinstance(node, DictConfig) else None
    if not target:
        raise ValueError(f"config group {group!r}: the selected option has no _target_")
    try:
        return get_object(str(target))
    except Exception as exc:  # hydra wraps import errors in its own types
        raise ImportError(f"config group {group!r}: cannot import _target_ {target!r}: {exc}") from exc


def _fmt(value: Any) -> str:
    if isinstance(value, DictConfig | ListConfig):
        value = OmegaConf.to_container(value, resolve=False)
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _type_name(hint: Any) -> str:
    if hint is type(None):
        return "null"
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(hint))
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(hint))
    if origin is not None:
        args = ", ".join(_type_name(a) for a in typing.get_args(hint))
        return f"{getattr(origin, '__name__', str(origin))}[{args}]" if args else str(origin)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return "one of " + ", ".join(repr(m.name) for m in hint)
    return getattr(hint, "__name__", str(hint))


def _is_component(value: Any) -> bool:
    return isinstance(value, DictConfig) and "_target_" in value


def _conforms(value: Any, hint: Any) -> bool:
    """Whether a config value can be given for a parameter annotated ``hint`` (unknown hints pass)."""
    if hint is Any or hint is inspect.Parameter.empty or isinstance(hint, typing.TypeVar | str):
        return True  # no hint, or one that did not resolve here: nothing to check against
    if _is_component(value):
        return True  # a nested component: checked on its own against its target
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_conforms(value, a) for a in args)
    if origin is typing.Literal:
        return value in args
    if origin is typing.Annotated:
        return _conforms(value, args[0])
    if hint is type(None) or hint is None:
        return value is None
    if value is None:
        return False
    if origin in (list, tuple, Sequence, typing.Sequence, set, frozenset) or hint in (list, tuple):
        if not isinstance(value, ListConfig | list | tuple):
            return False
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(_conforms(v, a) for v, a in zip(value, args, strict=True))
        inner = args[0] if args else Any
        return all(_conforms(v, inner) for v in value)
    if origin in (dict, Mapping, typing.Mapping) or hint in (dict, Mapping):
        return isinstance(value, DictConfig | dict)
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if hint in (Path, os.PathLike) or (isinstance(hint, type) and issubclass(hint, os.PathLike)):
        return isinstance(value, str | Path)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return isinstance(value, hint) or value in hint.__members__ or value in {m.value for m in hint}
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return isinstance(value, DictConfig | dict)
    return True  # a runtime object type (an index, an encoder...): whatever the target makes of it


def _hints(fn: Callable[..., Any]) -> dict[str, Any]:
    while isinstance(fn, functools.partial):  # a factory made by partial: the function's own hints
        fn = fn.func
    target = fn.__init__ if inspect.isclass(fn) else fn
    try:
        return typing.get_type_hints(target)
    except Exception:  # a hint that does not resolve here (optional dependency): check keys only
        return {}


def _check_value(path: str, value: Any, hint: Any) -> None:
    if not _conforms(value, hint):
        raise ConfigError(f"{path}: expected {_type_name(hint)}, got {_fmt(value)}")
    dc = _dataclass_in(hint)
    if dc is not None and isinstance(value, DictConfig) and not _is_component(value):
        check_fields(path, value, dc)
        check_builds(path, dc, value)
    elif _is_component(value):
        check_component_node(path, value)


def check_range(path: str, value: Any, fld: dataclasses.Field) -> None:
    """``value`` (each item, for a list; null passes) within the range ``fld`` declares, if any."""
    from experiments.config.schemas import RANGE

    bounds = fld.metadata.get(RANGE)
    if bounds is None or value is None:
        return
    low, high = bounds
    many = isinstance(value, ListConfig | list | tuple)
    for v in value if many else [value]:
        if isinstance(v, bool) or not isinstance(v, int | float):
            continue  # null, or a type error that _check_value reports
        if not (math.isfinite(v) and (low is None or v >= low) and (high is None or v <= high)):
            wanted = " and ".join(t for t in (low is not None and f">= {low}", high is not None and f"<= {high}") if t)
            raise ConfigError(f"{path}: expected {'every item ' if many else ''}{wanted}, got {_fmt(value)}")


def _options(node: DictConfig) -> dict[str, Any] | None:
    """``node``'s options as plain values (null when an interpolation resolves only later, e.g.
    hydra:runtime: checked then)."""
    try:
        values = OmegaConf.to_container(node, resolve=True)
    except Exception:
        return None
    return {k: v for k, v in values.items() if k not in HYDRA_KEYS}


def _value_error(path: str, exc: ValueError) -> ConfigError:
    """``exc`` as a config error naming the key at fault (``decomposer.alpha: ...``)."""
    option = exc.option if isinstance(exc, InputError) else None
    return ConfigError(f"{path}.{option}: {exc}" if option else f"{path}: {exc}")


def check_builds(path: str, cls: type, node: DictConfig) -> None:
    """Build the dataclass ``cls`` from ``node`` so that its own checks (``__post_init__``) run now."""
    obj = _options(node)
    if obj is None:
        return
    try:
        cls(**obj)
    except ValueError as exc:
        raise _value_error(path, exc) from None
    except Exception:  # a field that needs a built object, not a mapping: checked when it is built
        return


def check_own_options(path: str, fn: Callable[..., Any], node: DictConfig) -> None:
    """A component's own option checks (``check_options``, ``rdd.checks``): its declared ranges,
    applied to the config's values without building it or its runtime objects."""
    checker = getattr(fn, "check_options", None)
    opts = _options(node) if callable(checker) else None
    if opts is None:
        return
    try:
        checker(**opts)
    except ValueError as exc:
        raise _value_error(path, exc) from None


def _dataclass_in(hint: Any) -> type | None:
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return hint
    for a in typing.get_args(hint):
        if isinstance(a, type) and dataclasses.is_dataclass(a):
            return a
    return None


def check_fields(path: str, node: DictConfig, schema: type) -> None:
    """``node``'s keys must be fields of the dataclass ``schema``, each value of its field's type."""
    fields = {f.name: f for f in dataclasses.fields(schema)}
    hints = typing.get_type_hints(schema)
    for key in node:
        where = f"{path}.{key}" if path else str(key)
        if key not in fields:
            raise ConfigError(f"{where}: unknown key (given {_fmt(node[key])}); "
                              f"{path or 'the config'} has {sorted(fields)}")
        value = _raw(node, key)
        _check_value(where, value, hints.get(key, Any))
        check_range(where, value, fields[key])


def _raw(node: DictConfig, key: Any) -> Any:
    """The value at ``key`` with interpolations resolved (a missing env var reads as null)."""
    value = node._get_node(key)
    if value is None or value._is_none():
        return None
    if isinstance(value, DictConfig | ListConfig) and not value._is_interpolation():
        return value
    try:
        return node[key]
    except Exception:
        return None


def _options_owner(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Whose parameters a node's keys are: a classmethod factory that passes ``**options`` on to its
    class (``RDDDecomposer.calibrated``) has its class's options and checks."""
    owner = getattr(fn, "__self__", None)
    try:
        forwards = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(fn).parameters.values())
    except (TypeError, ValueError):
        return fn
    return owner if inspect.isclass(owner) and forwards else fn


def check_component_node(path: str, node: DictConfig, fn: Any = None) -> None:
    """A ``_target_`` node: its target imports, every key is a parameter of it, of the hinted type
    (``fn``: the target, when the caller has resolved it already)."""
    if fn is None:
        try:
            fn = target_callable(node, path)
        except (ImportError, ValueError) as exc:
            raise ConfigError(f"{path}._target_: {exc}") from None
    fn = _options_owner(fn)
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return
    open_kwargs = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    hints = _hints(fn)
    # A dataclass target (policy.train: TrainConfig): its fields' ranges, then its own checks.
    own_fields = {f.name: f for f in dataclasses.fields(fn)} if inspect.isclass(fn) and dataclasses.is_dataclass(fn) else {}
    for key in node:
        if key in HYDRA_KEYS:
            continue
        where = f"{path}.{key}"
        if key not in params:
            if open_kwargs:
                continue
            raise ConfigError(f"{where}: unknown option (given {_fmt(node[key])}) of {node._target_}; "
                              f"it takes {sorted(p for p in params if p != 'self')}")
        value = _raw(node, key)
        _check_value(where, value, hints.get(key, params[key].annotation))
        if key in own_fields:
            check_range(where, value, own_fields[key])
    if own_fields:
        check_builds(path, fn, node)
    check_own_options(path, fn, node)


def validate_config(cfg: DictConfig, schema: type | None = None,
                    components: Sequence[str] | None = None) -> None:
    """Raise :class:`ConfigError` naming the first unknown or mistyped key of ``cfg``."""
    from experiments.config.schemas import COMPONENT_GROUPS, RunConfig

    schema = schema or RunConfig
    components = COMPONENT_GROUPS if components is None else components
    fields = {f.name: f for f in dataclasses.fields(schema)}
    hints = typing.get_type_hints(schema)
    keys = [k for k in cfg if k != "hydra"]
    for key in keys:  # unknown keys first: no component module needs importing to report them
        if key not in fields:
            raise ConfigError(f"{key}: unknown key (given {_fmt(_raw(cfg, key))}); the config's keys are "
                              f"{sorted(fields)}")
    # the run's own keys before the components (whose targets import torch and friends)
    for key in sorted(keys, key=lambda k: k in components):
        value = _raw(cfg, key)
        if key in components:
            if _is_component(value):
                check_component_node(str(key), value)
            elif key == "decomposer" and isinstance(value, DictConfig) and set(value) == {"planner"}:
                # a row that decomposes nothing and evaluates its own planner (decomposer=none)
                check_component_node("decomposer.planner", value.planner)
            elif value is not None and not (isinstance(value, DictConfig) and len(value) == 0):
                raise ConfigError(f"{key}: expected a `_target_` node (an option of conf/{key}/), "
                                  f"got {_fmt(value)}")
            continue
        _check_value(str(key), value, hints.get(key, Any))
        check_range(str(key), value, fields[key])
    if schema is RunConfig:
        check_relations(cfg)


def check_relations(cfg: DictConfig) -> None:
    """Ranges two keys make together: a closed-loop run's evaluation episodes (test-split indices
    ``seed * eval.seed_stride + i``) lie inside the test split and apart from other seeds' episodes."""
    from experiments.config.schemas import SPLIT_SIZE

    if str(OmegaConf.select(cfg, "mode")).split(".")[-1] != "hierarchical":
        return
    n, stride, seed = int(cfg.eval.episodes_per_task), int(cfg.eval.seed_stride), int(cfg.seed)
    if n > stride:
        raise ConfigError(f"eval.episodes_per_task: expected <= eval.seed_stride={stride} (each seed evaluates "
                          f"its own {stride} test episodes), got {n}")
    if seed * stride + n > SPLIT_SIZE:
        raise ConfigError(f"seed: expected <= {(SPLIT_SIZE - n) // stride} with eval.seed_stride={stride} and "
                          f"eval.episodes_per_task={n} (the test split holds {SPLIT_SIZE} episodes), got {seed}")
