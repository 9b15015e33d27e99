"""Option checks shared by every component: each option's range is declared once, by its component.

A component declares a rule per option (:func:`whole`, :func:`number`, :func:`one_of`, :data:`FLAG`)
and checks its arguments with them when it is built. A class also exposes the same check as the
classmethod ``check_options(**options)``, which needs none of its runtime objects and does no work,
so a front end can check a configuration's options before anything runs (the harness's config
validator calls it on every ``_target_`` that has one). A bad value raises :class:`InputError`
naming the component, the option and the accepted range, with ``option`` set so the front end can
name the key or flag its user typed (``decomposer.alpha``, ``--alpha``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

from rdd.errors import InputError

# (owner, option, value) -> the checked value (an int for a whole number, a float for a number)
Rule = Callable[[str, str, Any], Any]


def check_int(owner: str, name: str, value: Any, minimum: int | None = None, allow_none: bool = False,
              maximum: int | None = None) -> int | None:
    """``value`` as an int (integral numbers only, no bools) within ``[minimum, maximum]``."""
    if value is None and allow_none:
        return None
    low = "" if minimum is None else f">= {minimum}"
    high = "" if maximum is None else f"<= {maximum}"
    bounds = " and ".join(x for x in (low, high) if x)
    ok = (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(float(value))
          and float(value).is_integer())
    if not ok:
        raise InputError(f"{owner}: option {name} must be a whole number{' ' + bounds if bounds else ''}, "
                         f"got {value!r}", option=name)
    out = int(value)
    if (minimum is not None and out < minimum) or (maximum is not None and out > maximum):
        raise InputError(f"{owner}: option {name} must be {bounds}, got {value!r}", option=name)
    return out


def check_float(owner: str, name: str, value: Any, minimum: float | None = None, maximum: float | None = None,
                exclusive_min: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a finite float within ``[minimum, maximum]`` (``(minimum, ...`` when exclusive)."""
    if value is None and allow_none:
        return None
    low = "" if minimum is None else f"{'>' if exclusive_min else '>='} {minimum}"
    high = "" if maximum is None else f"<= {maximum}"
    bounds = " and ".join(x for x in (low, high) if x)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(float(value)):
        raise InputError(f"{owner}: option {name} must be a finite number{' ' + bounds if bounds else ''}, "
                         f"got {value!r}", option=name)
    out = float(value)
    low_bad = minimum is not None and (out <= minimum if exclusive_min else out < minimum)
    if low_bad or (maximum is not None and out > maximum):
        raise InputError(f"{owner}: option {name} must be {bounds}, got {value!r}", option=name)
    return out


def check_choice(owner: str, name: str, value: Any, choices: Sequence[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    if value not in choices:
        raise InputError(f"{owner}: option {name} must be one of {list(choices)}, got {value!r}", option=name)
    return value


# ----------------------------------------------------------------------------- rules
def whole(minimum: int | None = None, maximum: int | None = None, *, allow_none: bool = False) -> Rule:
    """A whole number in ``[minimum, maximum]`` (null too, with ``allow_none``)."""
    return lambda owner, name, value: check_int(owner, name, value, minimum, allow_none, maximum)


def number(minimum: float | None = None, maximum: float | None = None, *, exclusive_min: bool = False,
           allow_none: bool = False) -> Rule:
    """A finite number in ``[minimum, maximum]`` (``(minimum, ...`` when exclusive; null with ``allow_none``)."""
    return lambda owner, name, value: check_float(owner, name, value, minimum, maximum, exclusive_min, allow_none)


def one_of(*choices: Any) -> Rule:
    """One of ``choices``."""
    return lambda owner, name, value: check_choice(owner, name, value, choices)


FLAG = one_of(True, False)


def check_options(owner: str, rules: Mapping[str, Rule], options: Mapping[str, Any],
                  prefix: str = "") -> dict[str, Any]:
    """``options`` with each one that ``rules`` names checked and converted; the others as given.

    ``prefix`` names options nested in another (``uvd_options.`` + ``gamma``); there an option no rule
    names is an error, since nothing else checks the nested keys.
    """
    out: dict[str, Any] = {}
    for key, value in options.items():
        if key in rules:
            out[key] = rules[key](owner, f"{prefix}{key}", value)
        elif prefix:
            raise InputError(f"{owner}: unknown option {prefix}{key}; accepted: {', '.join(rules)}",
                             option=f"{prefix}{key}")
        else:
            out[key] = value
    return out


def check_fields(obj: Any, owner: str, rules: Mapping[str, Rule]) -> None:
    """The fields of ``obj`` (a dataclass instance, from its ``__post_init__``) that ``rules`` name."""
    check_options(owner, rules, {key: getattr(obj, key) for key in rules})


class CheckedOptions:
    """Mixin of a component class whose options' ranges are its :attr:`OPTION_RULES`.

    Its constructor calls :meth:`check_options` on its arguments; a front end calls it on a config's
    options before building anything.
    """

    OPTION_RULES: ClassVar[Mapping[str, Rule]] = {}
    OPTION_KIND: ClassVar[str] = "component"  # the owner in messages: "<kind> <name>"
    name: str

    @classmethod
    def option_owner(cls) -> str:
        """What error messages name as the owner of the options."""
        return f"{cls.OPTION_KIND} {getattr(cls, 'name', cls.__name__)}"

    @classmethod
    def check_options(cls, **options: Any) -> dict[str, Any]:
        """``options`` checked against :attr:`OPTION_RULES` (others as given), building nothing."""
        return check_options(cls.option_owner(), cls.OPTION_RULES, options)


__all__ = ["FLAG", "CheckedOptions", "Rule", "check_choice", "check_fields", "check_float", "check_int", "check_options", "number", "one_of",
           "whole"]
