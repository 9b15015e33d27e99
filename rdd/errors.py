"""The library's one error type for bad input: data files, their fields and the options given.

A :class:`InputError` message is one line naming the file (and the episode and field) or the option
at fault, so a command-line front end prints it as it is, without a traceback. It is a
``ValueError``, so callers that already catch those keep working.
"""

from __future__ import annotations

import contextlib
import signal
from typing import Any

__all__ = ["InputError", "Terminated", "UsageError", "interrupt_on_sigterm", "restore_sigterm"]


class InputError(ValueError):
    """Bad input: the one-line message names the file, episode, field or option at fault."""

    def __init__(self, message: str, *, option: str | None = None) -> None:
        super().__init__(message)
        # The parameter at fault, when it is one: a front end names it as its user typed it
        # (``--max-len`` on the command line, ``decomposer.max_len`` in a config).
        self.option = option


class UsageError(Exception):
    """A command was called wrongly (a flag, a combination of flags): printed as one line, exit status 2."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler, ``docker stop``, ``timeout``) raised where the process was, so every
    ``finally`` runs and removes its temporaries, as Ctrl-C does."""


def _raise_terminated(signum: int, _frame) -> None:
    raise Terminated(signal.Signals(signum).name)


def interrupt_on_sigterm() -> Any:
    """Turn SIGTERM into :class:`Terminated` in this process (from its main thread; elsewhere, where
    Python allows no handler, SIGTERM keeps its default); returns the handler it replaced, to restore."""
    with contextlib.suppress(ValueError):
        return signal.signal(signal.SIGTERM, _raise_terminated)
    return None


def restore_sigterm(previous: Any) -> None:
    """Put back the SIGTERM handler that :func:`interrupt_on_sigterm` replaced (None: it replaced none)."""
    if previous is not None:
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGTERM, previous)
