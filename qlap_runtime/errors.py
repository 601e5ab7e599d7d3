"""Errors that end a command or a run with one line (no traceback): the bottom layer, so that
every layer may raise them and the command line reports them (docs/architecture.md, Layers)."""

from __future__ import annotations


class CliError(Exception):
    """An expected error of the command line: main prints ``qlap COMMAND: message`` on one
    line and exits with :attr:`code` (2: a bad input)."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


class WorldFailed(CliError):
    """A world's ``step`` raised: the run stops after the outputs of what was learned so far
    are written; the command line reports it in one line (exit status 1)."""

    def __init__(self, world: str, step: int, exc: BaseException) -> None:
        detail = " ".join(str(exc).split()) or "(no message)"
        super().__init__(f"world {world} failed at step {step}: {type(exc).__name__}: "
                         f"{detail[:300]}; what was learned so far is written", code=1)
        self.world = world
        self.step = step
