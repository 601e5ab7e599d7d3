"""The `qlap` command line, run as a user would (a subprocess)."""

import json
import subprocess
import sys


def qlap(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qlap_runtime.cli", *args],
                          capture_output=True, text=True, timeout=300)


def test_run_headless_writes_knowledge_summary_and_checkpoint(tmp_path):
    out = tmp_path / "run"
    r = qlap("run", "--headless", "--quiet", "--world", "core", "--steps", "10000",
             "--seed", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 10000
    assert summary["placement"] == "embedded"          # the default placement
    assert summary["steps_per_s"] > 0
    knowledge = json.loads((out / "knowledge.json").read_text())
    assert knowledge["step"] == 9999
    assert len(knowledge["dbns"]) == summary["dbns"] > 0
    assert (out / "checkpoints" / "step-0010000" / "learner.json").exists()
    assert "landmarks learned" in r.stdout


def test_bad_world_and_bad_flags_give_clear_errors():
    r = qlap("run", "--world", "nosuchworld", "--steps", "10")
    assert r.returncode == 2
    assert "nosuchworld" in r.stderr
    r = qlap("run", "--steps", "-5")
    assert r.returncode == 2
    assert "positive integer" in r.stderr
    r = qlap("run", "--lag", "5000", "--steps", "10")
    assert r.returncode == 2
    assert "--lag 5000: must be in [0, 2000)" in r.stderr
    r = qlap("run", "--headless", "--placement", "sync", "--steps", "10", "--record", "x.mcap")
    assert r.returncode == 2
    assert "--placement embedded" in r.stderr
    r = qlap("run", "--placement", "nowhere")
    assert r.returncode == 2
    assert "nowhere" in r.stderr


def test_show_and_eval_on_a_run(tmp_path):
    out = tmp_path / "run"
    r = qlap("run", "--quiet", "--world", "core2d", "--steps", "3000", "--babble-steps",
             "1000", "--seed", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    r = qlap("show", str(out))
    assert r.returncode == 0, r.stderr
    assert "landmarks learned" in r.stdout
    assert "actions with plans" in r.stdout
    r = qlap("show", str(out / "checkpoints" / "final"))
    assert r.returncode == 0, r.stderr
    r = qlap("eval", "--world", "core2d", "--checkpoint", str(out / "checkpoints" / "final"),
             "--task", "move_block", "--trials", "3", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["n_trials"] == 3
    assert res["policy"] == "qlap"
    assert -3.01 <= res["mean_reward"] <= 9.99
    assert sum(g["trials"] for g in res["by_goal"].values()) == 3
    # A goal the 3,000-step agent has no plan for ([0]): the note says the figures are a random
    # policy's, though the goal held in some steps (counted apart, not as steps without a plan).
    r = qlap("eval", "--world", "core2d", "--checkpoint", str(out / "checkpoints" / "final"),
             "--task", "move_block", "--trials", "3", "--goal", "h_x.dot=0")
    assert r.returncode == 0, r.stderr
    assert "note: the agent had no plan for h_x.dot=0 in any step" in r.stdout, r.stdout
    r = qlap("eval", "--world", "core2d", "--policy", "random", "--task", "move_block",
             "--trials", "12")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "mean reward" in lines[0]
    # Each goal the trials drew, on a line of its own (move_block draws one of three).
    per_goal = [ln.split()[0] for ln in lines[1:]]
    assert len(per_goal) >= 2 and set(per_goal) <= {"T_L.dot=+", "T_R.dot=-", "T_T.dot=+"}
    r = qlap("eval", "--world", "core2d", "--checkpoint", str(out / "checkpoints" / "final"),
             "--task", "move_block", "--trials", "2", "--goal", "T_L.dot=+")
    assert r.returncode == 0, r.stderr
    assert "pursuing T_L.dot=+" in r.stdout
    for goal, error in (("nope.dot=+", "unknown variable 'nope.dot'"),
                        ("T_L.dot", "expected VAR=VALUE"),
                        ("T_L.dot=up", "T_L.dot (change) has no value 'up'")):
        r = qlap("eval", "--world", "core2d", "--checkpoint",
                 str(out / "checkpoints" / "final"), "--task", "move_block", "--goal", goal)
        assert r.returncode == 2 and error in r.stderr, r.stderr
    r = qlap("eval", "--world", "core2d", "--task", "move_block")
    assert r.returncode == 2
    assert "--checkpoint is required" in r.stderr
    r = qlap("show", str(tmp_path))
    assert r.returncode == 2


def test_help_lists_every_command():
    r = qlap("--help")
    for cmd in ("run", "show", "eval", "snapshot", "worlds", "router", "record", "echo"):
        assert cmd in r.stdout


def test_a_closed_pipe_ends_the_command_quietly(monkeypatch, capsys):
    """``qlap worlds | head -1``: once the reader has gone, writing raises BrokenPipeError;
    the command ends with 141 (128 + SIGPIPE, as a shell reports it) and no error line."""
    from qlap_runtime import cli

    class ClosedPipe:
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            pass

    monkeypatch.setattr("sys.stdout", ClosedPipe())
    assert cli.main(["worlds"]) == 141
    assert capsys.readouterr().err == ""


def test_eval_trace_records_every_step_and_changes_nothing(tmp_path):
    """`qlap eval --trace`: one record per policy step, trials numbered from 0 with steps from
    0, the waits counted as the result says, each trial's reward — and the same trials as
    without a trace (tracing reads the agent, it does not steer it)."""
    out, trace = tmp_path / "run", tmp_path / "trace.jsonl"
    r = qlap("run", "--headless", "--placement", "sync", "--quiet", "--world", "pong",
             "--steps", "40000", "--babble-steps", "10000", "--seed", "1", "--out", str(out))
    assert r.returncode == 0, r.stderr
    ck = str(out / "checkpoints" / "final")
    plain = json.loads(qlap("eval", "--checkpoint", ck, "--task", "pong_volley", "--trials",
                            "6", "--json").stdout)
    r = qlap("eval", "--checkpoint", ck, "--task", "pong_volley", "--trials", "6",
             "--trace", str(trace), "--json")
    assert r.returncode == 0, r.stderr
    traced = json.loads(r.stdout)
    assert traced["rewards"] == plain["rewards"]
    lines = [json.loads(ln) for ln in trace.read_text().splitlines()]
    steps = [rec for rec in lines if "step" in rec]
    ends = [rec for rec in lines if "reward" in rec]
    assert len(steps) == traced["policy_steps"] == plain["policy_steps"]
    assert [e["trial"] for e in ends] == list(range(6))
    assert [e["reward"] for e in ends] == traced["rewards"]
    for trial in range(6):
        numbers = [rec["step"] for rec in steps if rec["trial"] == trial]
        assert numbers == list(range(len(numbers))) and numbers
    waits = [rec for rec in steps if rec["waiting"]]
    assert len(waits) == traced["waiting_steps"] > 0       # pong's plans wait for the ball
    assert all(rec["mode"] == "goal" and rec["calls"] for rec in waits)
    assert all(rec["goal"] in ("b_x.dot=+", "b_x.dot=-") and set(rec["motor"]) == {"u"}
               for rec in steps)
    r = qlap("eval", "--checkpoint", ck, "--task", "pong_volley", "--trace", str(tmp_path))
    assert r.returncode == 2 and f"--trace {tmp_path}: is a directory" in r.stderr
    r = qlap("eval", "--world", "pong", "--policy", "random", "--task", "pong_volley",
             "--trace", str(trace))
    assert r.returncode == 2 and "a trace needs --policy qlap" in r.stderr
    # An existing file is never overwritten (it might be a checkpoint's own agent.json).
    before = trace.read_bytes()
    r = qlap("eval", "--checkpoint", ck, "--task", "pong_volley", "--trials", "1",
             "--trace", str(trace))
    assert r.returncode == 2 and f"--trace {trace}: exists: give a new file" in r.stderr
    assert trace.read_bytes() == before
