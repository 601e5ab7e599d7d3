"""Writes off the step chain: one job at a time in a thread of its own (docs/decisions.md 81,
107).

A periodic checkpoint (``save_step_checkpoint``: JSON, npz and the lzma of the histories, then
the retention) takes about 0.5 s for a 30,000-step core agent and 2.2 s for a 250,000-step one;
written from the loop, it was a quarter of the synchronous loop's time late in a long run.
:class:`CheckpointWriter` takes a copy of the agent on the loop (``Agent.checkpoint_copy``,
0.085 s at 250,000 core steps, where a deep copy took 0.2 s,
docs/decisions.md 125) and writes the copy in such a thread, most of it with the GIL released
(lzma, deflate, ``fsync``).
:meth:`Background.wait` joins the job in flight and raises its error, before the next job and
before the run's final files.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from qlap_runtime.qlap.checkpoint import save_step_checkpoint, step_name


class Background:
    """At most one job at a time; its error is raised by the next :meth:`start` or
    :meth:`wait`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def start(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in a thread once the job before it is done."""
        self.wait()
        self.thread = threading.Thread(target=self._run, args=(fn, args), name=self.name,
                                       daemon=True)
        self.thread.start()

    def _run(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fn(*args)
        except BaseException as exc:            # raised in the caller's thread by wait()
            self.error = exc

    def wait(self) -> None:
        """Join the job in flight; raise its error."""
        error = self.join()
        if error is not None:
            raise error

    def join(self) -> BaseException | None:
        """Join the job in flight; return its error instead of raising it (for a caller that
        is already failing with an error of its own)."""
        if self.thread is not None:
            self.thread.join()
            self.thread = None
        error, self.error = self.error, None
        return error


class CheckpointWriter:
    """A run's periodic checkpoints ``step-N``, written off the caller's loop: :meth:`save`
    copies the agent now and writes the copy in a :class:`Background` thread; the files are
    those the live agent would give (docs/decisions.md 81). A write's error (a full disk) is
    raised by the next :meth:`save` or by :meth:`wait`, which the run calls before its final
    files."""

    def __init__(self) -> None:
        self.background = Background("checkpoint")

    def save(self, agent: Any, root: Path, step: int, world: str | None,
             keep: int | None, world_state: Any = None, copy_agent: bool = True
             ) -> Path | None:
        """Checkpoint ``root/step-NNNNNNN`` of ``agent`` as it is now; its path (None when
        ``keep`` is 0: no checkpoint). ``copy_agent`` False: nothing will change the agent any
        more (the run's last step), so it is written from the agent itself, at once."""
        if keep == 0:
            return None
        self.background.wait()                # the write before: one copy alive at a time
        if copy_agent:
            self.background.start(save_step_checkpoint, agent.checkpoint_copy(), root, step,
                                  world, keep, world_state)
        else:
            save_step_checkpoint(agent, root, step, world, keep, world_state)
        return Path(root) / step_name(step)

    def wait(self) -> None:
        """Join the write in flight; raise its error."""
        self.background.wait()

    def join(self) -> BaseException | None:
        """Join the write in flight; return its error (see :meth:`Background.join`)."""
        return self.background.join()
