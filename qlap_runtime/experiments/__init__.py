"""The experiments of chapter 7 as a product: ``qlap experiment NAME``.

Each experiment of §7.4–7.11 of J. Mugan, *Autonomous Qualitative Learning of Distinctions and
Actions in a Developing Agent*, PhD dissertation, UT Austin, 2010, is data (:mod:`.spec`,
:mod:`.registry`): worlds, conditions (QLAP with parameters or ablations, or a baseline of
:mod:`.baselines`), tasks, steps, agents and what to plot. :mod:`.sweep` expands one into agent
runs and evaluations, :mod:`.engine` runs them in parallel (a local process pool or Ray),
resumably, :mod:`.stats` and :mod:`.figures` summarise them as §7.3 does, and :mod:`.report`
writes ``RESULTS.md``. Documented in docs/experiments.md.
"""

from .spec import ExperimentError as ExperimentError

__all__ = ["ExperimentError"]
