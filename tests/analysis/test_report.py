"""qlap report: the figures of issue 9's table from a knowledge dict built by hand, and from a
real run."""

import json
import subprocess
import sys

import pytest

from qlap_runtime.analysis.report import (
    format_report,
    knowledge_figures,
    main_report,
    narrow_values,
)
from qlap_runtime.analysis.runs import AnalysisError, load_knowledge
from qlap_runtime.telemetry import pretty


def lm(lb: float, ub: float, source: str = "dbn") -> dict:
    label = f"{lb:.6g}" if lb == ub else f"[{lb:.6g}, {ub:.6g}]"
    return {"lb": lb, "ub": ub, "label": label, "source": source, "step": 0}


def dbn(kind: str) -> dict:
    return {"kind": kind, "label": "⟨…⟩", "brel": None, "entropy": 1.0, "plan": False}


KNOWLEDGE = {
    "step": 249_999, "k": 18, "k_learned": True,
    "landmarks": {
        "u_x": [lm(-335.0, -333.0), lm(0.0, 0.0, "initial"), lm(290.0, 330.0),
                lm(880.0, 881.0)],
        "u_y": [lm(-982.208, -982.203), lm(0.0, 0.0, "initial")],
        "T_T": [lm(-1.7118, -1.71173), lm(-1.71169, -1.71169)],
        "h_x": [],
    },
    "dbns": [dbn("change"), dbn("change"), dbn("change"), dbn("magnitude")],
    "actions": [
        {"variable": "h_x.dot", "value": "[+]", "label": "a(h_x.dot, [+])",
         "reliability": 0.34, "calls": 50, "plans": []},
        {"variable": "T_L.dot", "value": "[+]", "label": "a(T_L.dot, [+])",
         "reliability": 0.05, "calls": 20, "plans": [{"id": 1}]},
    ],
}


def test_figures_of_a_knowledge_dict_by_hand():
    f = knowledge_figures(KNOWLEDGE)
    assert (f["k"], f["change_dbns"], f["magnitude_dbns"]) == (18, 3, 1)
    assert f["landmarks"] == {"u_x": 4, "u_y": 2, "T_T": 2, "h_x": 0}
    assert f["landmarks_median"] == 2.0                       # of 0, 2, 2, 4
    assert (f["landmarks_max"], f["landmarks_max_variable"]) == (4, "u_x")
    # u_y's 0.005-wide landmark (< 0.1 % of 982), T_T's 0.00007-wide landmark and the
    # 0.00004-wide interval between it and the point −1.71169
    assert [(n["variable"], n["value"]) for n in f["narrow"]] == [
        ("u_y", "[-982.208, -982.203]"), ("T_T", "[-1.7118, -1.71173]"),
        ("T_T", "(-1.71173, -1.71169)")]
    assert f["narrow"][2]["width"] == pytest.approx(4e-5)
    assert f["u_x"]["plus"] == ["[290, 330]"] and f["u_x"]["minus"] == ["[-335, -333]"]
    acts = f["actions"]
    assert acts["a(h_x.dot, [+])"] == {"rel": 0.34, "plan": False, "plans": 0, "calls": 50}
    assert acts["a(T_L.dot, [+])"]["plan"] is True
    assert acts["a(T, true)"] == {"rel": None, "plan": False, "plans": 0, "calls": 0}


def test_narrow_against_a_resolution():
    lms = [lm(1.0, 1.0), lm(1.005, 1.2), lm(2.0, 2.004)]
    assert narrow_values(lms) == []                            # 0.1 % rule: none
    got = narrow_values(lms, resolution=0.01)
    assert [n["value"] for n in got] == ["(1, 1.005)", "[2, 2.004]"]


def test_text_table_has_reference_runs_and_mean():
    other = dict(KNOWLEDGE, k=6, dbns=[dbn("change")])
    text = format_report([knowledge_figures(KNOWLEDGE), knowledge_figures(other)], ["a", "b"])
    k_line = next(x for x in text.splitlines() if x.startswith("window k"))
    assert k_line.split()[-3:] == ["18", "6", "12.0"] and "≈ 6" in k_line
    rel_line = next(x for x in text.splitlines()
                    if x.startswith(f"rel {pretty('a(h_x.dot, [+])')}"))
    assert "0.97" in rel_line and "0.34 no plan" in rel_line and "plan 0/2" in rel_line
    assert "[288.89, 331.27]" in text and "[290, 330]" in text


def test_report_of_runs_as_json(runs, tmp_path):
    (tmp_path / "hand").mkdir()
    (tmp_path / "hand" / "knowledge.json").write_text(json.dumps(KNOWLEDGE))
    out = json.loads(main_report([tmp_path / "hand", runs[0]], as_json=True))
    assert list(out["runs"]) == ["hand", "s1"]
    real = json.loads((runs[0] / "knowledge.json").read_text())
    s1 = out["runs"]["s1"]
    assert s1["change_dbns"] == sum(d["kind"] == "change" for d in real["dbns"])
    assert s1["k"] == real["k"]
    assert out["mean"]["k"] == pytest.approx((18 + real["k"]) / 2)
    assert out["reference"]["actions"]["a(h_x.dot, [+])"]["rel"] == 0.97
    # a checkpoint directory gives its agent's knowledge, the same as knowledge.json's
    ck = load_knowledge(runs[0] / "checkpoints" / "final")
    assert len(ck["dbns"]) == len(real["dbns"]) and ck["k"] == real["k"]


def test_cli_hook(runs, tmp_path):
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "report", str(runs[0])],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "window k (App. C)" in r.stdout and "Table 8.1" in r.stdout
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "report", "/nonexistent"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "/nonexistent: no such directory" in r.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "report", str(empty)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "neither knowledge.json" in r.stderr, r.stderr


def test_resolutions_come_from_the_learner(runs, monkeypatch):
    from qlap_runtime.analysis.report import resolutions_of
    from qlap_runtime.qlap.perception import Perception

    monkeypatch.setattr(Perception, "resolution", lambda self, var: 0.25 + var, raising=False)
    res = resolutions_of(runs[0])                        # the run's final checkpoint
    real = json.loads((runs[0] / "knowledge.json").read_text())
    assert set(res) == set(real["landmarks"])            # every motor and magnitude
    assert res["u_x"] == 0.25 and res["u_y"] == 1.25     # table order: u_x, u_y, …
    assert resolutions_of(runs[0] / "nowhere") == {}


def test_a_zero_landmark_is_reported_as_0_never_minus_0():
    from qlap_runtime.analysis.report import unsigned_zero

    assert [unsigned_zero(t) for t in ("-0", "[-0, 5]", "[-10, -0]", "-0.5", "-05", "0")] == \
        ["0", "[0, 5]", "[-10, 0]", "-0.5", "-05", "0"]


def test_runs_of_different_worlds_are_not_averaged(runs, tmp_path):
    """As `qlap curve`: one report compares runs of one world (summary.json's world)."""
    other = tmp_path / "other"
    other.mkdir()
    (other / "knowledge.json").write_text(json.dumps(KNOWLEDGE))
    (other / "summary.json").write_text(json.dumps({"world": "pong"}))
    world = json.loads((runs[0] / "summary.json").read_text())["world"]
    with pytest.raises(AnalysisError, match=rf"different worlds \({world}, pong\)"):
        main_report([runs[0], other])
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "report", str(runs[0]),
                        str(other)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "one report compares runs of one world" in r.stderr
