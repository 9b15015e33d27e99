"""Build a component from its config node; what exists only at run time is passed explicitly.

A component config is a ``_target_`` node (often ``_partial_: true``) naming the class or factory
that builds the component; its keys are that target's options. Everything else reaches the
target at its call site, by keyword:

* the run's *runtime objects*, one name each (:data:`rdd.registry.RUNTIME_OBJECTS`): ``database``
  (the sub-task database of the training episodes), ``encoder`` (the visual encoder) and ``cache``
  (the embedding cache). A component takes one by having a parameter of that name, which its config
  leaves unset; the pipeline passes exactly those (``experiments.run.graph.Run.runtime``), and
  :func:`rdd.registry.construct` makes the call, as it does for ``python -m rdd``. Other components
  are composed in the config, not passed: ``index: ${index}`` hands RDD the ``index`` group's choice.
* the call site's own arguments (``task=`` for the env, ``plans=`` for the oracle planner).

A parameter without a default that neither the config, the runtime objects nor the call site
fill fails here, before the target runs, naming the component and the parameter.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from experiments.config.validate import ConfigError, check_component_node, target_callable
from rdd import registry
from rdd.registry import RUNTIME_OBJECTS


def runtime_names(node: DictConfig, group: str) -> tuple[str, ...]:
    """The runtime objects the component of ``node`` takes (its parameters named in RUNTIME_OBJECTS)."""
    return _call_names(node, group, target_callable(node, group))[0]


def _call_names(node: DictConfig, group: str, fn: Any) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The runtime objects ``fn`` takes (as :func:`rdd.registry.runtime_names` reads them) and its
    parameters without a default; a runtime object that the config sets fails here."""
    # One reading of the signature serves both checks, so a run asks the registry once per component.
    params = registry.parameters(fn)
    names = tuple(name for name in RUNTIME_OBJECTS if name in params)
    for name in names:
        if node.get(name) is not None:
            raise ConfigError(f"{group}.{name}: `{name}` is a runtime object ({RUNTIME_OBJECTS[name]}) "
                              f"that the run passes to {node._target_}; remove it from the config")
    return names, tuple(name for name, p in params.items() if p.default is inspect.Parameter.empty)


@dataclass(frozen=True)
class Resolved:
    """A component node resolved and checked once: its ``_target_``, the runtime objects it takes and
    its parameters without a default."""

    node: DictConfig
    group: str
    target: Any
    runtime: tuple[str, ...]
    required: tuple[str, ...]


def resolve(node: DictConfig | Resolved, group: str) -> Resolved:
    """Resolve ``node``'s target once, check its options and its runtime-object keys."""
    if isinstance(node, Resolved):
        return node
    fn = target_callable(node, group)
    check_component_node(group, node, fn)
    return Resolved(node, group, fn, *_call_names(node, group, fn))


def check_call(component: Resolved, given: Iterable[str] = ()) -> None:
    """Fail naming the component and parameter when a required parameter would be left unfilled.

    ``given`` are the names the call site passes (runtime objects and its own arguments).
    """
    node = component.node
    given = set(given) | {key for key in node if node.get(key) is not None}
    unset = [name for name in component.required if name not in given]
    if unset:
        raise ConfigError(
            f"{component.group} ({node._target_}): parameter {unset[0]!r} is not set by the config and is not a "
            f"runtime object the run passes (those are {', '.join(RUNTIME_OBJECTS)}: name the "
            "parameter after one of them, or give it a default)")


def component_factory(node: DictConfig | Resolved, group: str) -> functools.partial:
    """The ``_target_`` with the config's options bound (``node``: a config node, or one :func:`resolve`
    checked already); the caller passes the rest."""
    from hydra.utils import instantiate

    component = resolve(node, group)
    partial = instantiate(component.node, _partial_=True)
    if not isinstance(partial, functools.partial):
        raise TypeError(f"config group {group!r}: {component.node._target_} did not give a partial")
    return partial


def instantiate_component(node: DictConfig | Resolved, group: str, runtime: Mapping[str, Any] | None = None,
                          **kwargs: Any) -> Any:
    """Build the component of ``node`` (a config node, or one :func:`resolve` made) with exactly the
    runtime objects it takes, and ``kwargs``.

    ``runtime`` must hold every runtime object the target takes (:func:`runtime_names`) and no
    other; ``kwargs`` are the call site's own arguments (they override config values).
    """
    from hydra.utils import instantiate

    component = resolve(node, group)
    runtime = dict(runtime or {})
    check_call(component, [*runtime, *kwargs])
    # A partial from the config, called with the runtime objects: they never pass through
    # OmegaConf (which would copy or reject them).
    partial = instantiate(component.node, _partial_=True)
    return registry.construct(partial, runtime, f"{group} ({component.node._target_})", **kwargs)
