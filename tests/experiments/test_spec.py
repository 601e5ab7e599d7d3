"""Experiments as data: the registry of §7.4–7.11, the --quick preset, and the validation of
--set and --ablation (one-line errors, exit code 2, before anything runs)."""

import dataclasses

import pytest

from qlap_runtime.cli import main
from qlap_runtime.experiments.registry import EXPERIMENTS, get
from qlap_runtime.experiments.spec import ExperimentError, configure, parse_set, qlap_params
from qlap_runtime.experiments.sweep import plan

NAMES = ["core-tasks", "transfer", "extraneous", "dbn-count", "landmarks-vs-random",
         "two-blocks", "contingent", "pong", "ablations"]


def test_the_experiments_of_issue_11():
    assert list(EXPERIMENTS) == NAMES
    for exp in EXPERIMENTS.values():
        labels = [a.label for a in exp.arms]
        assert len(set(labels)) == len(labels)
        for panel in exp.panels:
            assert set(panel.arms) <= set(labels)
            for arm, versus in panel.tests:
                assert {arm, versus} <= set(labels)
        for ref in exp.reference:
            assert ref.task in exp.tasks and {ref.arm, ref.versus} <= set(labels)
    assert len(get("ablations").arms) == 9                   # QLAP and the eight of §7.11
    assert len(get("ablations").reference) == 24             # Table 7.4
    assert len(get("extraneous").reference) == 15            # Table 7.2
    assert len(get("core-tasks").reference) == 9             # Figs. 7.2–7.4 (d)–(f)


def test_list_one_line_each(capsys):
    assert main(["experiment", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_quick_preset(name):
    exp = configure(get(name), quick=True)
    assert exp.agents == 2 and exp.steps <= 30_000 and exp.trials == 20 and exp.quick_mode
    sweep = plan(exp, "/nonexistent")
    assert sweep.runs and all(s.steps <= 30_000 for s in sweep.runs.values())
    if exp.tasks:
        assert all(ar.steps for ar in sweep.arms.values())     # something to evaluate
    assert configure(get(name), quick=True, agents=3).agents == 3   # options override it


def test_transfer_aligns_its_second_half():
    sweep = plan(configure(get("transfer"), quick=True), "/x")
    t, s = sweep.arms["transfer"], sweep.arms["from scratch"]
    assert sweep.runs[t.runs[0]].world == "core:transfer:15000"
    assert t.eval_world == "core" and s.eval_world == "core"
    assert [x - t.offset for x in t.steps] == list(s.steps) == [5000, 10000, 15000]


def test_runs_are_shared_and_named_by_their_spec():
    a = plan(configure(get("core-tasks"), quick=True), "/x")
    b = plan(configure(get("ablations"), quick=True), "/x")
    assert set(a.arms["QLAP"].runs) == set(b.arms["QLAP"].runs)     # the same QLAP core runs
    assert not set(b.arms["no IAC"].runs) & set(b.arms["QLAP"].runs)
    c = plan(configure(get("core-tasks"), quick=True, sets={"theta_sr": 0.8}), "/x")
    assert not set(c.arms["QLAP"].runs) & set(a.arms["QLAP"].runs)
    assert set(c.arms["Tile-10"].runs) == set(a.arms["Tile-10"].runs)  # --set: QLAP only


def test_set_is_typed_by_the_params_field():
    assert parse_set("theta_sr=0.8") == ("theta_sr", 0.8)
    assert parse_set("babble_steps=5000") == ("babble_steps", 5000)
    assert parse_set("k_fixed=none") == ("k_fixed", None)
    assert parse_set("k_fixed=6") == ("k_fixed", 6)
    exp = configure(get("pong"), sets=dict([parse_set("babble_steps=1e4")]),
                    ablations=["no_iac"])
    cond = exp.arms[0].condition
    assert dict(cond.params) == {"babble_steps": 10_000} and cond.ablations == ("no_iac",)
    assert qlap_params(dict(cond.params), cond.ablations).ablations.no_iac


@pytest.mark.parametrize(("argv", "message"), [
    (["core-tasks", "--set", "nope=1"], "--set nope: unknown Params field (see "),
    (["core-tasks", "--set", "theta_rs=0.7"],
     "--set theta_rs: unknown Params field (did you mean theta_sr? see"),
    (["core-tasks", "--set", "no_iac=1"], "--set no_iac: a switch of §7.11, not a Params "
     "field; use --ablation no_iac"),
    (["core-tasks", "--set", "theta_sr"], "expected name=value"),
    (["core-tasks", "--set", "theta_sr=high"], "--set theta_sr=high: expected float"),
    (["core-tasks", "--set", "babble_steps=2.5"], "expected int"),
    (["core-tasks", "--set", "theta_sr=2"], "Params.theta_sr must lie in [0, 1]"),
    (["core-tasks", "--set", "ablations=x"], "use --ablation"),
    (["core-tasks", "--ablation", "bogus"], "unknown ablation 'bogus'"),
    (["core-tasks", "--ablation", "no_targeted", "--ablation", "all_targeted"],
     "no_targeted and all_targeted contradict each other"),
    (["ablations", "--ablation", "no_targeted"],
     "arm 'all targeted': ablations no_targeted and all_targeted contradict"),
    (["nope"], "unknown experiment 'nope'"),
    ([], "give an experiment NAME"),
    (["pong", "--address", "127.0.0.1:6379"], "--address goes with --engine ray"),
    (["transfer", "--steps", "10000"], "fewer than one checkpoint interval"),
    (["pong", "--every", "15000"], "must be a multiple of the checkpoint interval"),
])
def test_bad_options_are_one_line_errors(capsys, tmp_path, argv, message):
    assert main(["experiment", *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and err.startswith("qlap experiment:")
    assert not any(tmp_path.iterdir())                        # nothing ran


def test_bad_numbers_are_refused_by_argparse(capsys):
    with pytest.raises(SystemExit):
        main(["experiment", "pong", "--agents", "0"])
    assert "positive integer" in capsys.readouterr().err


def test_configure_refuses_bad_counts():
    with pytest.raises(ExperimentError, match="--agents must be a positive integer"):
        configure(get("pong"), agents=0)
    frozen = get("pong")
    with pytest.raises(dataclasses.FrozenInstanceError):
        frozen.agents = 3  # type: ignore[misc]
