"""A tiny experiment for the engine and report tests: core2d, 2,000 steps, a checkpoint every
1,000, QLAP against a Q-learner on random landmarks, two agents each (about two seconds)."""

from pathlib import Path
from typing import Any

import pytest

from qlap_runtime.experiments.engine import JOB_FUNCTIONS
from qlap_runtime.experiments.spec import (
    Arm,
    Condition,
    Experiment,
    Panel,
    Preset,
    QTableConfig,
    ReferenceStat,
)

TINY = Experiment(
    name="tiny", section="§0", title="a tiny experiment", claim="QLAP does something.",
    arms=(Arm("QLAP", "core2d", Condition("QLAP", "qlap", params=(("babble_steps", 500),))),
          Arm("random landmarks", "core2d",
              Condition("random landmarks", "qtable",
                        qtable=QTableConfig("random", range_steps=500)))),
    tasks=("move_block",),
    panels=(Panel("a", "both", ("QLAP", "random landmarks"),
                  (("random landmarks", "QLAP"),), "QLAP does better"),),
    figures=("curves", "bars", "dbn_count", "calls"),
    agents=2, steps=2000, trials=2, checkpoint_every=1000, eval_every=1000,
    exclude_fraction=0.4,
    reference=(ReferenceStat("move_block", "random landmarks", "QLAP", 12.5, 0.001,
                             "Fig. 0"),),
    notes=("The reference says so.",), figure_refs="Fig. 0", quick=Preset())


class InlineBackend:
    """The scheduler's backend, run in this process one job at a time (the jobs themselves
    are the real ones); counts what it was given."""

    name = "inline"

    def __init__(self, slots: int = 2) -> None:
        self.slots = slots
        self.submitted: list[tuple[str, str]] = []
        self._n = 0

    def submit(self, kind: str, payload: str) -> int:
        self.submitted.append((kind, payload))
        self._n += 1
        return self._n

    def wait(self, handles: list[Any], timeout: float) -> list[tuple[Any, Any]]:
        h = handles[0]
        kind, payload = self.submitted[h - 1]
        try:
            return [(h, JOB_FUNCTIONS[kind](payload))]
        except Exception as exc:
            return [(h, exc)]

    def close(self, cancel: bool = False) -> None:
        pass


@pytest.fixture
def tiny_root(tmp_path: Path) -> Path:
    return tmp_path / "exp"
