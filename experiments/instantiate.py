"""Generic component instantiation: runtime objects go to whichever targets ask for them.

A component config is a ``_target_`` node (often ``_partial_: true``). Objects that only exist at run
time (the sub-task database, the encoder, ...) are offered as named *providers*; a provider is called
(and so built) only when the target's signature has a parameter of that name the config leaves
unset. No component is special-cased: a new decomposer that wants ``encoder`` gets it by naming it.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Mapping
from typing import Any

from omegaconf import DictConfig

Provider = Callable[[], Any]
HYDRA_KEYS = {"_target_", "_partial_", "_recursive_", "_convert_", "_args_"}


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


def _signature(fn: Callable[..., Any]) -> inspect.Signature | None:
    try:
        return inspect.signature(fn)
    except (TypeError, ValueError):
        return None


def wanted_providers(node: DictConfig, group: str, providers: Mapping[str, Provider]) -> list[str]:
    """Names of providers the target takes as parameters that the config leaves unset (or null)."""
    sig = _signature(target_callable(node, group))
    if sig is None:
        return []
    out = []
    for name in sig.parameters:
        if name in providers and node.get(name) is None:
            out.append(name)
    return out


def check_component(node: DictConfig, group: str) -> None:
    """Fail with a clear message when the config sets a key the target does not accept."""
    sig = _signature(target_callable(node, group))
    if sig is None:
        return
    params = sig.parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = sorted(k for k in node if k not in HYDRA_KEYS and k not in params)
    if unknown:
        raise ValueError(
            f"config group {group!r} ({node._target_}): unknown option(s) {unknown}; "
            f"the target accepts {sorted(p for p in params if p != 'self')}"
        )


def component_factory(node: DictConfig, group: str) -> functools.partial:
    """The ``_target_`` with the config's options bound; the caller passes the runtime objects."""
    from hydra.utils import instantiate

    check_component(node, group)
    partial = instantiate(node, _partial_=True)
    if not isinstance(partial, functools.partial):
        raise TypeError(f"config group {group!r}: {node._target_} did not give a partial")
    return partial


def instantiate_component(
    node: DictConfig,
    group: str,
    providers: Mapping[str, Provider] | None = None,
    **kwargs: Any,
) -> Any:
    """Instantiate ``node``; runtime objects from ``providers`` fill the parameters it asks for.

    ``kwargs`` are passed as given (they override config values). When the config is ``_partial_``
    the partial is completed here, so the caller always gets the finished object.
    """
    from hydra.utils import instantiate

    providers = providers or {}
    check_component(node, group)
    extra = dict(kwargs)
    for name in wanted_providers(node, group, providers):
        if name not in extra:
            extra[name] = providers[name]()
    # Build a partial from the config, then call it with the runtime objects: they never pass
    # through OmegaConf (which would copy or reject them).
    partial = instantiate(node, _partial_=True)
    if not isinstance(partial, functools.partial):
        raise TypeError(f"config group {group!r}: {node._target_} did not give a partial")
    return partial(**extra)
