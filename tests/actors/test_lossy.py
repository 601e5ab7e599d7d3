"""Dropped and delayed messages (issue 13, the chaos harness's last item): messages of the
lockstep topics lost or delayed on the way (``RunContext.faults``, qlap_runtime/bus/faults.py)
are asked for again from their writer's replay log, so the run still ends byte-identical to the
synchronous loop; a loss nothing can recover ends with the watchdog's one line naming the
actor and the step it waits for, never a hang."""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

import pytest

from qlap_runtime.bus.faults import Faults, FaultsError
from qlap_runtime.errors import expected_error
from qlap_runtime.placements.launcher import run_embedded
from qlap_runtime.runtime.watchdog import RunStalled

from .test_faults import BASE, context, sync_knowledge

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "chaos.py"


def _injected(summary: dict) -> dict[str, int]:
    out = {"dropped": 0, "delayed": 0}
    for result in summary["actors"].values():
        for k, v in result.get("injected", {}).items():
            out[k] += v
    return out


def _lossy_run(tmp_path: Path, run_id: str, faults: Faults) -> tuple[dict[str, int], str, str]:
    """An embedded run of BASE (seed 7) with ``faults``: what was injected, its knowledge and
    the synchronous loop's."""
    ctx = context(tmp_path, BASE, 7, run_id).with_(faults=faults.to_json(), stall_s=20)
    summary = run_embedded(ctx)
    return (_injected(summary), (tmp_path / "knowledge.json").read_text(),
            sync_knowledge(BASE, seed=7))


def test_lost_and_late_chain_messages_are_fetched_again(tmp_path):
    """Every lockstep topic loses 0.5 % and delays 0.5 % of its messages by 0.2 s (embedded,
    3,000 steps): the knowledge is the synchronous loop's. Without the refills the first loss
    stalls the run (the watchdog's RunStalled after 20 s)."""
    injected, knowledge, expected = _lossy_run(tmp_path, "t-lossy-chain",
                                               Faults(drop=0.005, delay=0.005, seed=3))
    assert injected["dropped"] >= 10 and injected["delayed"] >= 10, injected
    assert knowledge == expected


def test_lost_deltas_and_batch_contexts_are_fetched_again(tmp_path):
    """Half of the deltas and batch contexts lost, a quarter late (embedded): consumers
    waiting for a due delta, and batch actors for the executor's context, ask again."""
    injected, knowledge, expected = _lossy_run(
        tmp_path, "t-lossy-deltas",
        Faults(drop=0.5, delay=0.25, topics=("delta/dbn", "delta/landmarks", "batchctx"), seed=1))
    assert injected["dropped"] >= 3 and injected["delayed"] >= 1, injected
    assert knowledge == expected


def test_a_message_lost_for_good_ends_with_one_line_naming_the_wait(tmp_path):
    """``lost``: the dropped ``qstate`` is missing from perception's replay log too, so no one
    can recover it: the watchdog stops the run within its ``stall_s`` and names who waits for
    which step. With L = 0 the learners read ``qstate`` from the bus (with a lag they take the
    executor's batch copies, and the executor its percept in memory: decisions 72, 84)."""
    faults = Faults(drop=0.01, topics=("qstate",), seed=2, lost=True).to_json()
    ctx = context(tmp_path, BASE.replace(batch_lag=0), 7, "t-lossy-lost").with_(
        faults=faults, stall_s=3)
    t0 = time.monotonic()
    with pytest.raises(BaseException) as info:  # noqa: PT011 - RunStalled, maybe in a group
        run_embedded(ctx)
    assert time.monotonic() - t0 < 60
    leaf = expected_error(info.value)
    assert isinstance(leaf, RunStalled), info.value
    message = str(leaf)
    assert "\n" not in message and "waits for qstate(" in message, message


def test_a_malformed_fault_plan_is_one_line():
    for bad in ({"drop": 2}, {"drop": 0.6, "delay": 0.6}, {"topics": ["control"]},
                {"delay_s": -1}, {"often": 1}, [1, 2], {"drop": "x"}):
        with pytest.raises(FaultsError) as info:
            Faults.of(bad)
        assert "\n" not in str(info.value)
    assert Faults.of(None) is None and Faults.of({}) is None
    plan = Faults.of({"drop": 0.1, "topics": ["motor"]})
    assert plan is not None and plan.injector("sense") is None
    assert plan.injector("motor") is not None


def load_chaos():
    """scripts/chaos.py as a module (also for tests/actors/test_chaos.py)."""
    spec = importlib.util.spec_from_file_location("chaos", SCRIPT)
    chaos = importlib.util.module_from_spec(spec)
    sys.modules["chaos"] = chaos                # its dataclasses look their module up
    spec.loader.exec_module(chaos)
    return chaos


def test_one_chaos_trial_with_kills_drops_and_delays_ends_as_the_sync_loop(capsys):
    """The fast variant of scripts/chaos.py: processes, 3,000 steps, two SIGKILLs and 0.5 %
    of the lockstep messages dropped and 0.5 % delayed (the full one is under ``-m slow``)."""
    code = load_chaos().main(["--trials", "1", "--kills", "2", "--steps", "3000", "--stall-s", "20",
                          "--limit-s", "240", "--drop", "0.005", "--delay", "0.005"])
    lines = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(lines[-1])
    assert code == 0, lines
    assert summary["identical"] == 1 and summary["hung"] == 0, lines
    assert "dropped 0," not in lines[0], lines[0]
