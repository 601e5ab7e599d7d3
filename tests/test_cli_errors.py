"""Bad inputs to `qlap` give one line on stderr and a non-zero exit (issue 12, item 6), and the
conventions of item 7: --version, help with defaults, `qlap worlds` with descriptions and tasks.

Most cases call :func:`qlap_runtime.cli.main` (the `qlap` entry point) in-process; the ones
whose error came out of a trio nursery or the Textual app run the real command in a subprocess.
Unreachable endpoints are a local port just closed: the connection is refused at once."""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys

import pytest

import worlds
from qlap_runtime.cli import build_parser, main


def qlap(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def qlap_process(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qlap_runtime.cli", *argv],
                          capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)


def assert_one_line(code: int, err: str, *names: str) -> str:
    assert code not in (0, None), err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for name in names:
        assert name in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ------------------------------------------------------------------------ files and directories
def test_run_out_naming_an_existing_file(capsys, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                        "--steps", "10", "--out", str(afile))
    assert_one_line(code, err, str(afile), "not a directory")


def test_an_executor_actor_never_writes_into_another_run(capsys, tmp_path, closed_port):
    # Its outputs would truncate the run's metrics and replace its final checkpoint.
    (tmp_path / "metrics.jsonl").write_text('{"step": 1}\n')
    code, _, err = qlap(capsys, "actor", "executor", "--connect",
                        f"tcp/127.0.0.1:{closed_port}", "--run", "zz", "--out", str(tmp_path))
    assert_one_line(code, err, f"--out {tmp_path} already holds a run (metrics.jsonl)")
    assert code == 2 and (tmp_path / "metrics.jsonl").read_text() == '{"step": 1}\n'


def test_run_record_into_a_missing_directory(capsys, tmp_path):
    target = tmp_path / "missing" / "x.mcap"
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--steps", "10",
                        "--out", str(tmp_path / "run"), "--record", str(target))
    assert_one_line(code, err, "--record", str(target), "does not exist")
    assert not (tmp_path / "run").exists()          # refused before anything started


def test_a_recording_on_a_full_disk_stops_and_the_run_goes_on(tmp_path):
    # The recording streams to x.mcap.part, here a device that refuses every write (/dev/full,
    # ENOSPC): the run still writes what it learned, and says where the recording stopped.
    target, out = tmp_path / "x.mcap", tmp_path / "run"
    (tmp_path / "x.mcap.part").symlink_to("/dev/full")
    r = qlap_process("run", "--headless", "--quiet", "--steps", "600", "--babble-steps", "300",
                     "--out", str(out), "--record", str(target))
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    last = r.stderr.strip().splitlines()[-1]        # after the run's own header line
    assert f"--record {target}: the recording stopped after" in last
    assert "No space left on device" in last and "the run went on" in last
    assert (out / "knowledge.json").is_file() and (out / "checkpoints" / "final").exists()
    assert json.loads((out / "summary.json").read_text())["recording"]["error"]
    assert not target.exists()


@pytest.mark.parametrize("command", ["run", "record"])
def test_an_existing_recording_is_never_overwritten(capsys, tmp_path, command):
    target = tmp_path / "old.mcap"
    target.write_bytes(b"a recording")
    argv = (["run", "--headless", "--quiet", "--steps", "10", "--out", str(tmp_path / "run"),
             "--record", str(target)] if command == "run" else
            ["record", "--connect", "tcp/127.0.0.1:9", "--out", str(target)])
    code, _, err = qlap(capsys, *argv)
    assert_one_line(code, err, str(target), "exists", "never overwritten")
    assert target.read_bytes() == b"a recording" and not (tmp_path / "run").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs /proc")
def test_run_record_into_a_directory_that_refuses_files(capsys, tmp_path):
    """/proc exists but takes no new file: refused before the run starts, not after."""
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--steps", "10",
                        "--out", str(tmp_path / "run"), "--record", "/proc/x.mcap")
    assert_one_line(code, err, "--record /proc/x.mcap", "cannot write in /proc")
    assert not (tmp_path / "run").exists()


def test_snapshot_out_must_be_a_png(capsys, tmp_path):
    target = tmp_path / "s.jpg"
    code, _, err = qlap(capsys, "snapshot", "--out", str(target))
    assert_one_line(code, err, f"--out {target}: a snapshot is a PNG image")
    assert not target.exists()


def test_snapshot_out_into_a_missing_directory(capsys, tmp_path):
    target = tmp_path / "missing" / "scene.png"
    code, _, err = qlap(capsys, "snapshot", "--out", str(target))
    assert_one_line(code, err, "qlap snapshot", str(target), "does not exist")


def test_record_out_into_a_missing_directory(capsys, tmp_path, closed_port):
    target = tmp_path / "missing" / "x.mcap"
    code, _, err = qlap(capsys, "record", "--connect", f"tcp/127.0.0.1:{closed_port}",
                        "--out", str(target))
    assert_one_line(code, err, "qlap record", str(target), "does not exist")


# ------------------------------------------------------------------------ unreachable endpoints
@pytest.mark.parametrize("command", [["echo", "qlap/**"],
                                     ["record", "--out", "OUT", "--duration", "1"]])
def test_echo_and_record_to_an_unreachable_endpoint(tmp_path, closed_port, command):
    endpoint = f"tcp/127.0.0.1:{closed_port}"
    command = [str(tmp_path / "x.mcap") if a == "OUT" else a for a in command]
    r = qlap_process(command[0], "--connect", endpoint, *command[1:])
    line = assert_one_line(r.returncode, r.stderr, f"qlap {command[0]}", endpoint)
    assert "cannot connect" in line
    assert "ExceptionGroup" not in r.stderr


def test_tui_with_a_malformed_endpoint_or_run_id_exits_2_before_connecting(closed_port):
    r = qlap_process("tui", "--connect", "nope")
    assert_one_line(r.returncode, r.stderr, "qlap tui", "'nope' is not an endpoint")
    assert r.returncode == 2
    r = qlap_process("tui", "--connect", f"tcp/127.0.0.1:{closed_port}", "--run", "a/b")
    assert_one_line(r.returncode, r.stderr, "qlap tui: --run a/b: run id 'a/b'")
    assert r.returncode == 2 and "cannot connect" not in r.stderr


def test_tui_to_an_unreachable_endpoint(closed_port):
    endpoint = f"tcp/127.0.0.1:{closed_port}"
    r = qlap_process("tui", "--connect", endpoint)
    assert_one_line(r.returncode, r.stderr, "qlap tui", "cannot connect", endpoint)
    assert r.stdout == ""                            # the UI never started


# ------------------------------------------------------------------------ worlds
def test_unknown_gym_environment(capsys):
    code, _, err = qlap(capsys, "eval", "--policy", "random", "--world", "gym:NoSuchEnv-v0",
                        "--task", "x")
    assert_one_line(code, err, "gym:NoSuchEnv-v0", "NoSuchEnv")


def test_an_import_path_that_is_no_world_factory(capsys):
    code, _, err = qlap(capsys, "eval", "--policy", "random", "--world", "os.path:join",
                        "--task", "x")
    assert_one_line(code, err, "os.path:join", "not a world factory")


@pytest.mark.parametrize("spec", ["worlds:X", "mymod_that_is_not_there:make", "nosuchworld"])
def test_unknown_world_mentions_the_import_form(capsys, spec):
    code, _, err = qlap(capsys, "eval", "--policy", "random", "--world", spec, "--task", "x")
    line = assert_one_line(code, err, spec, "module:Factory", "core")
    assert "unknown world 'worlds'" not in line


def test_a_top_level_module_factory_is_a_world(capsys, tmp_path, monkeypatch):
    (tmp_path / "qlap_plugin_world.py").write_text(
        "import worlds\n\ndef make():\n    return worlds.make('core2d')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    world = worlds.make("qlap_plugin_world:make")
    assert "move_block" in world.tasks
    world.close()
    code, out, err = qlap(capsys, "eval", "--policy", "random", "--world",
                          "qlap_plugin_world:make", "--task", "move_block", "--trials", "1")
    assert code == 0, err
    assert "mean reward" in out
    # registered names come first: core:floating is the variant, not an import of "core"
    world = worlds.make("core:floating")
    assert world.name == "core:floating"
    world.close()


@pytest.mark.parametrize(("source", "problem"), [
    ("def make():\n    raise RuntimeError('boom in factory')\n",
     "its factory 'make' raised RuntimeError: boom in factory"),
    ("def make(:\n", "importing 'qlap_broken_world' failed: SyntaxError"),
    ("raise ValueError('bad at import')\n",
     "importing 'qlap_broken_world' failed: ValueError: bad at import"),
])
def test_a_plugin_world_that_fails_is_one_line(capsys, tmp_path, monkeypatch, source, problem):
    (tmp_path / "qlap_broken_world.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "qlap_broken_world", raising=False)
    for argv in (("eval", "--policy", "random", "--task", "x"),
                 ("run", "--headless", "--placement", "sync", "--steps", "10",
                  "--out", str(tmp_path / "out"))):
        code, _, err = qlap(capsys, *argv, "--world", "qlap_broken_world:make")
        assert_one_line(code, err, "qlap_broken_world:make", problem)
        sys.modules.pop("qlap_broken_world", None)


@pytest.mark.parametrize(("spec", "given"), [("pong:x", "pong has no variants, got 'x'"),
                                         ("core2d:x:y", "got 'x:y'")])
def test_a_variant_of_a_world_without_variants(capsys, spec, given):
    code, _, err = qlap(capsys, "eval", "--policy", "random", "--world", spec, "--task", "x")
    line = assert_one_line(code, err, spec, given)
    assert "None" not in line


def test_negative_babble_steps(capsys, tmp_path):
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                        "--steps", "10", "--babble-steps", "-3", "--out", str(tmp_path / "r"))
    assert_one_line(code, err, "--babble-steps", "-3")
    assert not (tmp_path / "r").exists()


def test_eval_takes_the_world_from_the_checkpoint(capsys, tmp_path):
    out = tmp_path / "pong"
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                        "--world", "pong", "--steps", "300", "--babble-steps", "100",
                        "--out", str(out))
    assert code == 0, err
    final = str(out / "checkpoints" / "final")
    code, stdout, err = qlap(capsys, "eval", "--checkpoint", final, "--task", "pong_volley",
                             "--trials", "1")
    assert code == 0, err
    assert stdout.startswith("pong pong_volley")
    code, _, err = qlap(capsys, "eval", "--checkpoint", final, "--task", "move_block",
                        "--trials", "1")
    assert_one_line(code, err, "pong", "move_block")


# ------------------------------------------------------------------------ conventions (item 7)
@pytest.mark.parametrize(("argv", "names"), [
    (("run", "--seed", "-1"), ("qlap run: error: argument --seed", "got -1", "qlap run --help")),
    (("run", "--hz", "inf"), ("argument --hz", "got inf")),
    (("eval", "--trials", "x"), ("qlap eval: error: argument --trials", "'x'")),
    (("record", "--duration", "nan"), ("argument --duration", "got nan")),
    (("run", "--listen", "garbage"), ("argument --listen", "'garbage'")),
    (("nope",), ("qlap: error: argument COMMAND", "see qlap --help")),
    (("run", "--bogus"), ("qlap run: error: unrecognized arguments: --bogus", "qlap run --help")),
])
def test_a_wrong_flag_is_one_line_naming_it(argv, names):
    r = qlap_process(*argv)
    assert r.returncode == 2
    assert_one_line(r.returncode, r.stderr, *names)


def test_version():
    r = qlap_process("--version")
    assert r.returncode == 0
    assert r.stdout.startswith("qlap ")
    assert r.stdout.split()[1][0].isdigit()


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def test_every_option_of_every_subcommand_has_help():
    parser = build_parser()
    missing = []
    for name, sub in _subparsers(parser).items():
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            if not (action.help or "").strip():
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
    assert not missing


def test_help_shows_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "trials of the task (default: 100)" in text
    assert "(default: the world the checkpoint records, else core)" in text
    assert "(default: 0)" in text                    # --seed: a default of 0 is shown
    with pytest.raises(SystemExit):
        main(["echo", "--help"])
    assert "(default: until Ctrl-C)" in " ".join(capsys.readouterr().out.split())


def test_worlds_lists_each_spec_with_description_and_tasks(capsys):
    code, out, _ = qlap(capsys, "worlds")
    assert code == 0
    lines = out.strip().splitlines()
    specs = worlds.registered()
    for spec in specs:
        line = next(ln for ln in lines if ln.split()[0] == spec)
        assert "tasks:" in line
        assert len(line.split("tasks:")[0].split()) > 2, line    # a description
    core = next(ln for ln in lines if ln.split()[0] == "core")
    assert "move_block" in core and "pickup" in core and "hit_floor" in core
    assert "pong_volley" in next(ln for ln in lines if ln.split()[0] == "pong")
    assert "module:Factory" in lines[-1]
    code, out, _ = qlap(capsys, "worlds", "--json")
    rows = {r["spec"]: r for r in json.loads(out)}
    assert set(rows) == set(specs)
    assert rows["core:secondary:aligned"]["tasks"] == ["hit_secondary", "pickup"]


# ------------------------------------------------------------------------ --resume (issue 13)
def test_resume_never_writes_over_the_source_run(capsys, tmp_path):
    run = tmp_path / "run"
    code, _, _ = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                      "--world", "core2d", "--steps", "300", "--out", str(run))
    assert code == 0
    before = {p: p.read_bytes() for p in (run / "knowledge.json", run / "summary.json")}
    final = run / "checkpoints" / "final"
    for out in (run, run / "more", tmp_path):
        code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                            "--world", "core2d", "--steps", "100", "--resume", str(final),
                            "--out", str(out))
        line = assert_one_line(code, err, "--resume", "would write over the run")
        assert str(run.resolve()) in line
    assert {p: p.read_bytes() for p in before} == before
    assert not (run / "more").exists()
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "sync",
                        "--world", "core2d", "--steps", "100", "--resume", str(final),
                        "--out", str(tmp_path / "resumed"))
    assert code == 0, err
    assert json.loads((tmp_path / "resumed" / "summary.json").read_text())["steps"] == 100


# ------------------------------------------------------------------------ process groups
@pytest.mark.parametrize("groups", ["bogus", "world+perception,executor",
                                    "world+perception+executor+planner,contingency",
                                    "world+perception+executor,planner+contingency+landmarks"])
def test_a_wrong_groups_value_is_one_line_naming_it(capsys, tmp_path, groups):
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "processes",
                        "--world", "core2d", "--steps", "10", "--groups", groups,
                        "--out", str(tmp_path / "r"))
    assert code == 2
    assert_one_line(code, err, "--groups", repr(groups))
    assert not (tmp_path / "r").exists()


def test_groups_go_with_the_processes_placement(capsys, tmp_path):
    code, _, err = qlap(capsys, "run", "--headless", "--quiet", "--placement", "embedded",
                        "--world", "core2d", "--steps", "10", "--groups", "each",
                        "--out", str(tmp_path / "r"))
    assert_one_line(code, err, "--groups each", "--placement processes")


def test_the_groups_layouts():
    from qlap_runtime.placements.groups import ACTORS, LAYOUTS, parse_groups

    assert parse_groups("two") == LAYOUTS["two"]
    assert parse_groups("each") == tuple((a,) for a in ACTORS)
    assert parse_groups("world+perception+executor+planner,contingency+landmarks") \
        == LAYOUTS["two"]
    assert sorted(a for g in LAYOUTS["two"] for a in g) == sorted(ACTORS)


@pytest.mark.parametrize("lag", ["-3", "2000", "100000"])
def test_a_lag_outside_the_batch_period_names_the_flag_and_the_bound(capsys, tmp_path, lag):
    code, _, err = qlap(capsys, "run", "--headless", "--world", "core2d", "--steps", "10",
                        "--lag", lag, "--out", str(tmp_path / "r"))
    line = assert_one_line(code, err, f"--lag {lag}", "[0, 2000)")
    assert "Params" not in line and code == 2
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("argv", [("run", "--headless", "--steps", "10", "--out", ""),
                                  ("show", "")])
def test_an_empty_path_is_refused(argv):
    r = qlap_process(*argv)          # --out '' was the current directory
    assert r.returncode == 2
    assert_one_line(r.returncode, r.stderr, "an empty path", f"qlap {argv[0]} --help")


def test_a_file_or_a_run_directory_given_for_a_checkpoint(capsys, tmp_path):
    note = tmp_path / "notes.txt"
    note.write_text("not a checkpoint")
    run_dir = tmp_path / "runs" / "s1"
    (run_dir / "checkpoints").mkdir(parents=True)
    code, _, err = qlap(capsys, "run", "--headless", "--world", "core2d", "--steps", "10",
                        "--resume", str(note), "--out", str(tmp_path / "r1"))
    assert code == 2
    assert_one_line(code, err, "--resume", "a file, not a checkpoint directory")
    code, _, err = qlap(capsys, "eval", "--checkpoint", str(run_dir), "--world", "core2d",
                        "--task", "move_block", "--trials", "1")
    line = assert_one_line(code, err, "is a run directory")
    assert code == 2 and str(run_dir / "checkpoints" / "final") in line


@pytest.mark.parametrize(("knowledge", "problem"), [
    ({}, "no field 'step'"),
    ({"step": 5, "k": 3, "landmarks": "x", "dbns": [], "actions": []},
     "'landmarks' is str, not dict"),
    ({"step": 5, "k": 3, "landmarks": {}, "dbns": [7], "actions": []},
     "an entry of 'dbns' is not an object"),
])
@pytest.mark.parametrize("command", ["show", "report"])
def test_a_knowledge_file_of_the_wrong_shape_is_one_line(capsys, tmp_path, knowledge, problem,
                                                         command):
    (tmp_path / "knowledge.json").write_text(json.dumps(knowledge))
    code, _, err = qlap(capsys, command, str(tmp_path))
    assert code == 2
    assert_one_line(code, err, "knowledge.json: not a run's knowledge", problem)


@pytest.mark.parametrize(("argv", "problem"), [
    (("show", "{missing}"), "{missing}: no such directory"),
    (("report", "{missing}"), "{missing}: no such directory"),
    (("eval", "--checkpoint", "{missing}", "--task", "move_block"),
     "{missing}: no such checkpoint directory"),
    (("run", "--headless", "--resume", "{missing}", "--steps", "10"),
     "{missing}: no such checkpoint directory"),
])
def test_a_directory_that_does_not_exist_is_named_as_such(capsys, tmp_path, argv, problem):
    missing = str(tmp_path / "not-there")
    code, _, err = qlap(capsys, *(a.format(missing=missing) for a in argv))
    assert_one_line(code, err, problem.format(missing=missing))


def test_echo_refuses_a_bad_key_and_a_zero_count_before_connecting(capsys, closed_port):
    endpoint = f"tcp/127.0.0.1:{closed_port}"
    code, _, err = qlap(capsys, "echo", "--connect", endpoint, "--count", "1", "bad key **//")
    line = assert_one_line(code, err, "KEY 'bad key **//': not a key expression")
    assert "cannot connect" not in line and "credentials" not in line
    r = qlap_process("echo", "--connect", endpoint, "--count", "0", "qlap/**")
    assert_one_line(r.returncode, r.stderr, "argument --count", "got 0")


@pytest.mark.parametrize(("text", "problem"), [
    ("{ bad json5", "line 1, column 1: expected array"),
    ("{ listen: { endpoints: 5 } }", "line 1, column 24: invalid type: integer `5`"),
])
def test_a_bad_router_config_file_is_one_line_with_its_place(capsys, tmp_path, text, problem):
    path = tmp_path / "router.json5"
    path.write_text(text)
    code, _, err = qlap(capsys, "router", "--config", str(path))
    line = assert_one_line(code, err, str(path), problem)
    assert ".rs:" not in line and "-->" not in line


def test_a_router_that_cannot_listen_names_the_endpoint(capsys):
    code, _, err = qlap(capsys, "router", "--listen", "tcp/999.1.1.1:7447")
    assert_one_line(code, err, "qlap router: cannot listen on tcp/999.1.1.1:7447: ")


def test_a_router_config_whose_users_file_is_missing_names_it(capsys, tmp_path):
    path = tmp_path / "router.json5"
    path.write_text('{ mode: "router", listen: { endpoints: ["tcp/127.0.0.1:0"] }, transport: '
                    '{ auth: { usrpwd: { dictionary_file: "no-such-users.txt" } } } }')
    code, _, err = qlap(capsys, "router", "--config", str(path))
    assert_one_line(code, err, f"qlap router: --config {path}: ",
                    "dictionary_file 'no-such-users.txt'")


def test_a_goal_given_twice_is_refused_not_replaced():
    r = qlap_process("eval", "--policy", "random", "--task", "move_block",
                     "--goal", "T_L.dot=+", "--goal", "T_R.dot=-")
    assert_one_line(r.returncode, r.stderr, "argument --goal: given twice")
    assert r.returncode == 2


def test_a_stopped_run_names_the_checkpoint_it_keeps(tmp_path):
    """What `qlap run` adds to the line of a run stopped by a failed write: its newest whole
    checkpoint (one with agent.json) and the command that goes on from it — with --placement
    sync for a realtime run's checkpoint, which holds no world state."""
    from qlap_runtime.cli import kept_checkpoint

    assert kept_checkpoint(None) == ""
    assert kept_checkpoint(tmp_path) == "; no checkpoint was kept"
    ck = tmp_path / "checkpoints"
    for step in ("step-0010000", "step-0020000"):
        (ck / step).mkdir(parents=True)
        (ck / step / "agent.json").write_text("{}")
    (ck / "step-0030000").mkdir()                       # an actor's part only: not whole
    newest = ck / "step-0020000"
    assert kept_checkpoint(tmp_path) == (
        f"; kept: {newest} (go on from it: qlap run --resume {newest} --placement sync "
        "--out NEW_DIR)")
    (newest / "world.json").write_text("{}")
    assert kept_checkpoint(tmp_path) == (
        f"; kept: {newest} (go on from it: qlap run --resume {newest} --out NEW_DIR)")


def test_resume_in_another_world_is_refused_before_the_run(capsys, tmp_path):
    """A checkpoint without world.json resumed with another --world: one line naming both
    worlds, before anything runs or is written (not a failed world at the first step)."""
    import shutil

    from qlap_runtime.agent_run import run_agent
    from qlap_runtime.qlap import Params

    world = worlds.make("core2d")
    try:
        run_agent(world, 600, 3, out=tmp_path / "a", params=Params(babble_steps=300))
    finally:
        world.close()
    ck = tmp_path / "ck"
    shutil.copytree(tmp_path / "a" / "checkpoints" / "final", ck)
    (ck / "world.json").unlink()
    code, _, err = qlap(capsys, "run", "--headless", "--placement", "sync", "--resume", str(ck),
                        "--world", "pong", "--steps", "10", "--out", str(tmp_path / "b"))
    assert_one_line(code, err, "--resume", str(ck), "--world 'pong'")
    assert not (tmp_path / "b").exists()


def test_listen_on_a_taken_port_is_refused_before_the_run(capsys, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, _, err = qlap(capsys, "run", "--headless", "--steps", "10", "--listen",
                            f"tcp/127.0.0.1:{port}", "--out", str(tmp_path / "run"))
    assert_one_line(code, err, f"--listen tcp/127.0.0.1:{port}", "cannot listen there")
    assert not (tmp_path / "run").exists()


def test_an_actor_refuses_a_runs_viewer_credentials(capsys, tmp_path):
    code, _, err = qlap(capsys, "actor", "world", "--connect", "tcp/127.0.0.1:9", "--run", "r1",
                        "--credentials", str(tmp_path / "bus-credentials.json"))
    assert_one_line(code, err, "--credentials", "viewer", "--user NAME")
