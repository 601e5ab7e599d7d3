"""Errors that end a command or a run with one line (no traceback): the bottom layer, so that
every layer may raise them and the command line reports them (docs/architecture.md, Layers)."""

from __future__ import annotations

import re
import sys


class CliError(Exception):
    """An expected error of the command line: main prints ``qlap COMMAND: message`` on one
    line and exits with :attr:`code` (2: a bad input)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


class ActorFailed(RuntimeError):
    """An actor died and could not be restarted: the run is stopped (the supervisor's and
    the watchdog's verdict; the command line names the checkpoint kept)."""


class WorldFailed(CliError):
    """A world's ``step`` raised: the run stops after the outputs of what was learned so far
    are written; the command line reports it in one line (exit status 1)."""

    def __init__(self, world: str, step: int, exc: BaseException) -> None:
        detail = " ".join(str(exc).split()) or "(no message)"
        super().__init__(f"world {world} failed at step {step}: {type(exc).__name__}: "
                         f"{detail[:300]}; what was learned so far is written", code=1)
        self.world = world
        self.step = step


def expected_error(exc: BaseException) -> BaseException | None:
    """The error to report in one line if ``exc`` is an expected one (a bad input, a file that
    cannot be written, an endpoint that cannot be reached, a world that cannot be made), looking
    inside exception groups (trio nurseries); None for a bug, whose traceback is wanted."""
    if isinstance(exc, BaseExceptionGroup):
        leaves = [expected_error(e) for e in exc.exceptions]
        if leaves and all(leaf is not None for leaf in leaves):
            return leaves[0]
        return None
    expected: list[type] = [CliError, OSError]
    for module, name in (("zenoh", "ZError"), ("gymnasium.error", "Error"),
                         ("worlds.registry", "WorldSpecError"),
                         ("qlap_runtime.runtime.supervisor", "ActorFailed"),
                         ("qlap_runtime.bus.config", "BusConfigError")):
        if module in sys.modules and isinstance(getattr(sys.modules[module], name, None), type):
            expected.append(getattr(sys.modules[module], name))
    return exc if isinstance(exc, tuple(expected)) else None


def one_line(exc: BaseException) -> str:
    """``exc`` as one line: an OSError as 'FILE: reason', Zenoh's source location dropped."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    text = re.sub(r"\s+at \S+\.rs:\d+\.?\s*$", "", str(exc).strip())
    return " ".join(text.split()) or type(exc).__name__
