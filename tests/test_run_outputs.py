"""What a run leaves behind (issue 12): the run directory by default, checkpoint retention and
``final`` as a link, the compact checkpoint format, the metrics log in every placement,
``qlap plot``, plain progress lines and the one-line errors of ``--out``."""

from __future__ import annotations

import errno
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import CheckpointError, load_agent, save_agent
from qlap_runtime.qlap.checkpoint.files import pack_rows, unpack_rows

WORLD = "core2d"
PARAMS = Params(babble_steps=1000)
TIME_KEYS = ("wall_s", "steps_per_s")


def qlap(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "qlap_runtime.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def sync_run(out: Path | None, steps: int, *, every: int = 1000, keep: int | None = None,
             params: Params = PARAMS, seed: int = 1, agent=None):
    import worlds
    from qlap_runtime.agent_run import run_agent

    world = worlds.make(WORLD)
    try:
        return run_agent(world, steps, seed, out, params=params, checkpoint_every=every,
                         keep_checkpoints=keep, agent=agent)
    finally:
        world.close()


def metrics(run: Path) -> list[dict]:
    from qlap_runtime.metrics import read_metrics

    return read_metrics(run / "metrics.jsonl")


def without_time(lines: list[dict]) -> list[dict]:
    return [{k: v for k, v in line.items() if k not in TIME_KEYS} for line in lines]


# --------------------------------------------------------------------------- run directory
def test_default_run_directory_is_created_and_printed(tmp_path):
    r = qlap("run", "--headless", "--quiet", "--placement", "sync", "--world", WORLD,
             "--steps", "1500", "--babble-steps", "500", "--seed", "4", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    m = re.search(r"^run directory: (runs/core2d-\d{8}-\d{6}-s4)$", r.stdout, re.M)
    assert m, r.stdout[:500]
    run = tmp_path / m[1]
    assert (run / "summary.json").is_file() and (run / "knowledge.json").is_file()
    assert (run / "checkpoints" / "final" / "agent.json").is_file()
    assert [line["step"] for line in metrics(run)] == [1000, 1500]
    assert f"wrote {m[1]}/" in r.stdout.split("run directory:")[-1]     # printed at the end
    assert not (tmp_path / "qlap-checkpoints").exists()


# --------------------------------------------------------------------------- retention, final
def test_outputs_are_readable_by_others_as_the_umask_allows(tmp_path):
    """Files written whole (temporary file + rename) get 0666 less the umask, as open() would
    give them, not mkstemp's 0600 (the run's credentials alone stay private)."""
    sync_run(tmp_path / "run", 1000)
    mask = os.umask(0o022)
    os.umask(mask)
    want = 0o666 & ~mask
    files = [tmp_path / "run" / n for n in ("knowledge.json", "summary.json")]
    files += sorted((tmp_path / "run" / "checkpoints" / "step-0001000").iterdir())
    assert {f.name: f.stat().st_mode & 0o777 for f in files} == \
        {f.name: want for f in files}


def test_retention_keeps_the_newest_n_and_final_links_to_the_last(tmp_path):
    from qlap_runtime.analysis.runs import find_checkpoints, load_knowledge
    from qlap_runtime.analysis.timeline import knowledge_timeline
    from qlap_runtime.cli import main

    run = tmp_path / "run"
    agent, _ = sync_run(run, 4000, keep=2)
    ck = run / "checkpoints"
    assert sorted(p.name for p in ck.iterdir()) == ["final", "step-0003000", "step-0004000"]
    assert (ck / "final").is_symlink() and os.readlink(ck / "final") == "step-0004000"
    final = load_agent(ck / "final")
    assert json.dumps(final.knowledge()) == json.dumps(agent.knowledge())
    assert [(c.name, c.step) for c in find_checkpoints(run, "run")] == [
        ("step-0003000", 3000), ("step-0004000", 4000)]
    assert [p.step for p in knowledge_timeline(run)] == [3000, 4000]
    assert load_knowledge(ck / "final")["step"] == 3999
    assert main(["show", str(ck / "final")]) == 0
    assert main(["eval", "--world", WORLD, "--checkpoint", str(ck / "final"),
                 "--task", "move_block", "--trials", "2"]) == 0
    assert main(["report", str(run)]) == 0
    # resume from final (a link) continues the run
    more, _ = sync_run(run, 1000, keep=2, agent=load_agent(ck / "final"))
    assert more.step_count == 4999
    assert sorted(p.name for p in ck.iterdir()) == ["final", "step-0004000", "step-0005000"]
    assert os.readlink(ck / "final") == "step-0005000"


def test_a_periodic_checkpoint_written_off_the_loop_is_the_agent_of_its_step(tmp_path):
    """docs/decisions.md 107: the synchronous loop writes a copy of the agent in a thread of
    its own and goes on; the files are those of the agent at that step, byte for byte, though
    the loop went on for 1,500 steps more."""
    sync_run(tmp_path / "run", 2500)
    at_1000, _ = sync_run(None, 1000)
    save_agent(at_1000, tmp_path / "direct", WORLD)
    written = tmp_path / "run" / "checkpoints" / "step-0001000"
    for name in ("agent.json", "learner.json"):
        assert (written / name).read_bytes() == (tmp_path / "direct" / name).read_bytes()
    assert load_agent(written).step_count == 999


def test_a_checkpoint_that_cannot_be_written_stops_the_run_with_its_error(tmp_path,
                                                                          monkeypatch):
    """A full disk in the writer's thread is not lost: the run stops with that error at the
    next checkpoint or at the end (decision 107), after the checkpoints before it."""
    from qlap_runtime.runtime import background

    real = background.save_step_checkpoint

    def full_disk_at_2000(agent, root, step, *args):
        if step == 2000:
            raise OSError(28, "No space left on device")
        return real(agent, root, step, *args)

    monkeypatch.setattr(background, "save_step_checkpoint", full_disk_at_2000)
    with pytest.raises(OSError, match="No space left"):
        sync_run(tmp_path / "run", 2500)
    assert (tmp_path / "run" / "checkpoints" / "step-0001000" / "agent.json").is_file()
    assert not (tmp_path / "run" / "knowledge.json").exists()


def test_a_checkpoint_directory_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """write_checkpoint_dir: a failed write leaves neither the checkpoint nor its temporary
    sibling; a write into a directory that already holds another actor's part keeps the part
    and moves agent.json in last."""
    from qlap_runtime.qlap.checkpoint import write_checkpoint_dir

    target = tmp_path / "checkpoints" / "step-0002000"

    def half_then_full(d: Path) -> None:
        (d / "learner.json").write_text("{}")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        write_checkpoint_dir(target, half_then_full)
    assert list((tmp_path / "checkpoints").iterdir()) == []

    target.mkdir()
    (target / "world.json").write_text('{"part": "world"}')
    order: list[str] = []

    def whole(d: Path) -> None:
        for name in ("learner.json", "agent.json", "agent.npz"):
            (d / name).write_text(name)

    real_replace = os.replace

    def watch(src, dst):
        order.append(Path(dst).name)
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", watch)
    write_checkpoint_dir(target, whole)
    monkeypatch.undo()
    assert order == ["agent.npz", "learner.json", "agent.json"]
    assert sorted(p.name for p in target.iterdir()) == ["agent.json", "agent.npz",
                                                        "learner.json", "world.json"]
    assert (target / "world.json").read_text() == '{"part": "world"}'
    assert list((tmp_path / "checkpoints").iterdir()) == [target]


def test_final_is_a_directory_when_it_differs_and_a_marker_where_links_fail(tmp_path,
                                                                            monkeypatch):
    from qlap_runtime.analysis.runs import find_checkpoints, load_knowledge

    run = tmp_path / "odd"
    sync_run(run, 2500)                          # the last step-N (2000) is not the final state
    final = run / "checkpoints" / "final"
    assert final.is_dir() and not final.is_symlink()
    assert [c.name for c in find_checkpoints(run, "odd")] == [
        "step-0001000", "step-0002000", "final"]

    none = tmp_path / "none"
    sync_run(none, 2000, keep=0)                 # no periodic checkpoints: final is a copy
    assert sorted(p.name for p in (none / "checkpoints").iterdir()) == ["final"]
    assert (none / "checkpoints" / "final").is_dir()

    def no_links(*a, **k):
        raise OSError(errno.EPERM, "links not supported")

    monkeypatch.setattr(os, "symlink", no_links)
    marked = tmp_path / "marked"
    agent, _ = sync_run(marked, 2000)
    final = marked / "checkpoints" / "final"
    assert final.is_file() and final.read_text().split() == ["qlap-checkpoint-link",
                                                             "step-0002000"]
    assert json.dumps(load_agent(final).knowledge()) == json.dumps(agent.knowledge())
    assert [c.step for c in find_checkpoints(marked, "marked")] == [1000, 2000]
    (marked / "knowledge.json").unlink()
    assert load_knowledge(marked)["step"] == 1999


# --------------------------------------------------------------------------- compact format
def test_rows_table_is_exact_for_nan_and_negative_zero():
    a = np.array([[0.0, -0.0, np.nan], [1.5, np.inf, -np.inf], [0.0, -0.0, np.nan]])
    b = np.array([[1.5, np.inf, -np.inf], [2.0, 3.0, 4.0]])
    packed = pack_rows({"a": a, "b": b, "c": np.arange(3)}, ["a", "b"])
    assert packed["_rows"].shape == (3, 3)                 # 5 rows, 3 distinct
    back = unpack_rows(dict(packed))
    assert back["a"].tobytes() == a.tobytes() and back["b"].tobytes() == b.tobytes()
    assert np.array_equal(back["c"], np.arange(3))


def _write_older(src: Path, dst: Path, version: int) -> None:
    """The checkpoint of ``src`` as an older writer left it. Version 1: every array in the npz
    under its own name, the plans' Q-tables in indented agent.json; version 2: compact, the
    Q-tables in agent.npz as they are, an npz entry per DBN or plan array."""
    from qlap_runtime.qlap.checkpoint.agent_files import _unpack_q
    from qlap_runtime.qlap.checkpoint.files import read_npz, ungroup_arrays
    from qlap_runtime.qlap.mdp import q_to_state

    dst.mkdir()
    for name in ("learner", "agent"):
        meta = json.loads((src / f"{name}.json").read_text())
        arrays = ungroup_arrays(read_npz(src / f"{name}.npz"))
        if version == 1:
            arrays = unpack_rows(arrays)
        meta["version"] = version
        if name == "agent":
            for plan in meta["plans"]:
                pid = plan["id"]
                q = _unpack_q(tuple(plan.pop("q_shape")), arrays.pop(f"plan.{pid}.q_na"),
                              arrays.pop(f"plan.{pid}.q_values"))
                if version == 1:
                    plan["q"] = q_to_state(q)
                else:
                    arrays[f"plan.{pid}.q"] = q
        np.savez_compressed(dst / f"{name}.npz", **arrays)
        (dst / f"{name}.json").write_text(json.dumps(meta, indent=1 if version == 1 else None))


def _steps(agent, world, obs, first: int, last: int):
    """Agent steps first..last-1 in ``world`` (as run_agent does, without its reset)."""
    for t in range(first, last):
        obs = world.step(agent.step(t, obs, discontinuity=bool(world.discontinuity)))
    return obs


def _state_bytes(agent) -> list[bytes]:
    """What must come back byte for byte: Q-tables, traces, stored activations and calls,
    the perception history, the random generator."""
    out = [json.dumps(agent.knowledge()).encode(), json.dumps(agent.rng.bit_generator.state,
                                                              sort_keys=True).encode(),
           agent.learner.perception.hist_x.tobytes()]
    for pid in sorted(agent.plans):
        pl = agent.plans[pid]
        out += [pl.q.tobytes(), pl.sarsa.e.tobytes(), pl.call_x.tobytes()]
    for i in sorted(agent.learner.dbns):
        out.append(agent.learner.dbns[i].act_x.tobytes())
    return out


def test_compact_checkpoints_resume_exactly_and_versions_1_and_2_still_load(tmp_path):
    import worlds
    from qlap_runtime.agent_run import params_for_world
    from qlap_runtime.qlap.agent import Agent

    def fresh():
        world = worlds.make(WORLD)
        agent = Agent(world.variables, params_for_world(world, Params(babble_steps=2000)),
                      seed=1)
        return agent, world, world.reset(seed=1)

    straight, w0, obs0 = fresh()
    _steps(straight, w0, obs0, 0, 10_000)
    w0.close()
    agent, world, obs = fresh()
    obs = _steps(agent, world, obs, 0, 8000)
    assert agent.plans, "the test needs plans (Q-tables) in the checkpoint"
    save_agent(agent, tmp_path / "v3", WORLD)
    loaded = load_agent(tmp_path / "v3")
    assert _state_bytes(loaded) == _state_bytes(agent)
    for version in (2, 1):                   # older checkpoints load to the very same state
        _write_older(tmp_path / "v3", tmp_path / f"v{version}", version)
        assert json.loads((tmp_path / f"v{version}" / "agent.json").read_text())["version"] \
            == version
        assert _state_bytes(load_agent(tmp_path / f"v{version}")) == _state_bytes(agent)
    _steps(loaded, world, obs, 8000, 10_000)      # and the resumed agent goes on exactly
    world.close()
    assert json.dumps(loaded.knowledge()) == json.dumps(straight.knowledge())
    meta = (tmp_path / "v3" / "agent.json").read_text()
    assert "\n" not in meta and '"q"' not in meta                     # compact, Q in the npz
    assert json.loads((tmp_path / "v3" / "learner.json").read_text())["version"] == 3
    with np.load(tmp_path / "v3" / "learner.npz") as z:      # grouped by field; rows in xz
        assert "dbn.*.cpt_s" in z.files and not any(k.startswith("dbn.0.") for k in z.files)
        assert "_rows.npy.xz" in z.files
    meta = json.loads(meta)
    meta["version"] = 7
    (tmp_path / "v3" / "agent.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=r"qlap-agent version 7 is not supported"):
        load_agent(tmp_path / "v3")


# --------------------------------------------------------------------------- metrics log
def test_metrics_log_is_the_same_in_the_sync_loop_embedded_actors_and_ui_driver(tmp_path):
    # Same seed and lag: the actor placements learn exactly what the synchronous loop learns,
    # so their metrics lines agree but for the times.
    for name, placement in (("sync", "sync"), ("embedded", "embedded")):
        r = qlap("run", "--headless", "--quiet", "--placement", placement, "--world", WORLD,
                 "--steps", "3000", "--babble-steps", "1000", "--seed", "3", "--lag", "500",
                 "--out", str(tmp_path / name))
        assert r.returncode == 0, r.stderr
    sync, embedded = metrics(tmp_path / "sync"), metrics(tmp_path / "embedded")
    assert [line["step"] for line in sync] == [1000, 2000, 3000]
    assert without_time(embedded) == without_time(sync)
    assert all(line["steps_per_s"] > 0 for line in sync + embedded)
    assert sync[-1]["babble_commands"] > 0 and sync[-1]["iac_babbles"] >= 0

    # The UI's local driver (lag 0, as `qlap run` in a terminal) against the sync loop.
    import worlds
    from tests.local_driver import finished_driver

    sync_run(tmp_path / "sync0", 2500, seed=3)
    world = worlds.make(WORLD)
    try:
        with finished_driver(world, seed=3, params=PARAMS, steps=2500, out=tmp_path / "ui",
                             world_spec=WORLD) as d:
            assert d.finished and d.error is None
    finally:
        world.close()
    ui = metrics(tmp_path / "ui")
    assert [line["step"] for line in ui] == [1000, 2000, 2500]
    assert without_time(ui) == without_time(metrics(tmp_path / "sync0"))
    assert (tmp_path / "ui" / "summary.json").is_file()
    assert (tmp_path / "ui" / "checkpoints" / "final" / "agent.json").is_file()


def test_metrics_log_survives_a_torn_line_and_a_resume(tmp_path):
    from qlap_runtime.metrics import MetricsLog, read_metrics

    agent, _ = sync_run(tmp_path / "run", 3000)
    log = tmp_path / "run" / "metrics.jsonl"
    whole = log.read_bytes()
    log.write_bytes(whole + b'{"step":4000,"wall_')             # a crash mid-line
    assert [line["step"] for line in read_metrics(log)] == [1000, 2000, 3000]
    w = MetricsLog(log, agent, start=2000)                     # resumed from step 2000
    w.write(2500, agent)
    w.close()
    assert [line["step"] for line in read_metrics(log)] == [1000, 2000, 2500]
    assert log.read_bytes().endswith(b"}\n")


@pytest.mark.skipif(sys.platform == "win32", reason="needs a POSIX pty")
@pytest.mark.timeout(180)
def test_the_ui_path_writes_its_run_directory_and_c_saves_into_it(tmp_path):
    import time

    from tests.tui.test_terminal import Terminal, _qlap_command

    def wait_for(what, limit: float = 120.0) -> None:
        deadline = time.monotonic() + limit
        while not what():
            assert term.proc.poll() is None, term.tail()
            assert time.monotonic() < deadline, term.tail()
            time.sleep(0.2)

    term = Terminal([*_qlap_command(), "run", "--world", WORLD, "--steps", "2000", "--seed",
                     "5"], cwd=tmp_path, columns=160, rows=48)
    try:
        # the agent process writes its outputs when the last step is done; the UI is up
        wait_for(lambda: "Runtime" in term.text()
                 and any((tmp_path / "runs").glob("*/summary.json")))
        term.send(b"c")
        wait_for(lambda: any((tmp_path / "runs").glob("*/checkpoints/step-*/agent.json")), 30)
        term.send(b"q")
        assert term.proc.wait(30) == 0, term.tail()
        term._reader.join(5)
        text = term.text()
    finally:
        term.close()
    (run,) = (tmp_path / "runs").iterdir()
    assert re.fullmatch(r"core2d-\d{8}-\d{6}-s5", run.name)
    assert f"run directory: runs/{run.name}" in text and f"wrote runs/{run.name}/" in text
    assert not (tmp_path / "qlap-checkpoints").exists()
    saved = [p.name for p in (run / "checkpoints").iterdir() if p.name.startswith("step-")]
    assert saved, "c saved no checkpoint into the run directory"
    assert (run / "checkpoints" / "final" / "agent.json").is_file()
    assert (run / "summary.json").is_file() and (run / "knowledge.json").is_file()
    assert [line["step"] for line in metrics(run)][:2] == [1000, 2000]
    # What `c` saved holds the world's state too, so the default placement resumes it exactly.
    (saved_dir,) = [run / "checkpoints" / name for name in saved]
    assert (saved_dir / "world.json").is_file()
    r = qlap("run", "--headless", "--quiet", "--resume", str(saved_dir), "--steps", "2500",
             "--out", str(tmp_path / "resumed"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "resumed" / "summary.json").read_text())["steps"] == 2500


# --------------------------------------------------------------------------- qlap plot
def test_qlap_plot_draws_metrics_and_the_curve(tmp_path):
    from qlap_runtime.analysis.curve import CurveRow, write_rows
    from qlap_runtime.cli import main

    run = tmp_path / "run"
    sync_run(run, 3000)
    assert main(["plot", str(run)]) == 0
    png = (run / "metrics.png").read_bytes()
    assert png.startswith(b"\x89PNG")
    rows = [CurveRow("run", s, "move_block", 1.0 + s / 1000, 0.2, 0.3, 10, 0, WORLD, "qlap",
                     f"step-{s:07d}") for s in (1000, 2000, 3000)]
    rows.append(CurveRow("random", None, "move_block", 0.5, 0.1, 0.1, 10, 0, WORLD, "random",
                         ""))
    write_rows(run / "curve.csv", rows)
    assert main(["plot", str(run)]) == 0
    assert (run / "metrics.png").read_bytes() != png            # now with the curve
    r = qlap("plot", str(tmp_path))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no metrics.jsonl" in r.stderr


# --------------------------------------------------------------------------- progress lines
def test_progress_lines_when_stdout_is_not_a_terminal_and_the_last_agrees(tmp_path):
    r = qlap("run", "--headless", "--placement", "sync", "--world", WORLD, "--steps", "3000",
             "--babble-steps", "1000", "--seed", "2", "--out", str(tmp_path / "run"))
    assert r.returncode == 0, r.stderr
    lines = re.findall(r"^step ([\d,]+)/3,000 .*$", r.stdout, re.M)
    assert [s.replace(",", "") for s in lines] == ["1000", "2000", "3000"], r.stdout[:600]
    last = re.search(r"^step 3,000/3,000 \(100%\)  ([\d,.]+) steps/s  DBNs (\d+)  plans (\d+)  "
                     r"landmarks (\d+)  done in", r.stdout, re.M)
    assert last, r.stdout[:600]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert float(last[1].replace(",", "")) == summary["steps_per_s"]
    assert [int(x) for x in last.groups()[1:]] == [summary["dbns"], summary["plans"],
                                                   summary["landmarks"]]
    assert f"{summary['steps_per_s']} steps/s" in r.stdout
    assert "━" not in r.stdout                                   # no progress-bar frame


# --------------------------------------------------------------------------- --out errors
def test_out_naming_a_file_is_a_one_line_error(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    r = qlap("run", "--headless", "--placement", "sync", "--world", WORLD, "--steps", "10",
             "--out", str(f))
    assert r.returncode == 2
    assert r.stderr.strip() == f"qlap run: --out {f}: exists and is not a directory"


@pytest.mark.parametrize(("code", "text"), [(errno.EROFS, "Read-only file system"),
                                            (errno.ENOSPC, "No space left on device")])
def test_unwritable_out_is_a_one_line_error_before_the_run(tmp_path, monkeypatch, capsys,
                                                           code, text):
    from qlap_runtime import cli

    def fail(*a, **k):
        raise OSError(code, text)

    if os.geteuid() != 0 and code == errno.EROFS:
        (tmp_path / "ro").mkdir(mode=0o500)                    # really read-only
        out = tmp_path / "ro" / "run"
        text = "Permission denied"
    else:
        monkeypatch.setattr(os, "fsync", fail)                 # the probe file's write
        out = tmp_path / "run"
    rc = cli.main(["run", "--headless", "--placement", "sync", "--world", WORLD, "--steps",
                   "100000", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.strip() == f"qlap run: --out {out}: cannot write there ({text})"
    assert not (out / "metrics.jsonl").exists()


def has_a_line(path: Path) -> bool:
    return path.is_file() and path.read_text().count("\n") > 0


def as_in_a_terminal() -> None:
    """A child's signals as a terminal's foreground job has them: a runner in the background
    (CI) ignores SIGINT, children inherit that, and an ignored signal stays ignored
    (``interrupt.heeded``)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


@pytest.mark.parametrize(("placement", "sig"), [("sync", "SIGINT"), ("sync", "SIGTERM"),
                                                ("embedded", "SIGTERM")])
def test_a_signal_stops_a_run_between_two_steps_with_its_outputs(tmp_path, placement, sig):
    """Ctrl-C or SIGTERM: the run ends between two steps as after its last one — knowledge,
    summary and checkpoints/final written — and says how to go on (exit 130); the actors
    take it as a viewer's ``quit``."""
    import signal
    import time

    out = tmp_path / "run"
    qlap = str(Path(sys.executable).parent / "qlap")
    p = subprocess.Popen([qlap, "run", "--headless", "--placement", placement, "--world", WORLD,
                          "--steps", "1000000", "--out", str(out), "--quiet"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=as_in_a_terminal)
    # An actor run stopped while a batch is in flight names its newest periodic checkpoint to
    # go on from (with none kept yet, it says so): wait for the first one there.
    first = out / "checkpoints" / "step-0010000" / "agent.json"
    try:
        deadline = time.monotonic() + 120
        while not (has_a_line(out / "metrics.jsonl") if placement == "sync"
                   else first.is_file()) and time.monotonic() < deadline:
            time.sleep(0.1)                 # the run has taken steps (the file comes first)
        p.send_signal(getattr(signal, sig))
        _, err = p.communicate(timeout=120)
    finally:
        p.kill()
        p.communicate()
    assert p.returncode == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert 0 < summary["steps"] < 1_000_000
    assert (out / "checkpoints" / "final" / "agent.json").is_file()
    assert f"interrupted after {summary['steps']:,} steps; what was learned is written" in err
    assert placement != "sync" or summary["interrupted_at"] == summary["steps"]
    assert "go on from it: qlap run --resume " in err


@pytest.mark.parametrize("placement", ["sync", "embedded"])
def test_an_ignored_hangup_stays_ignored(tmp_path, placement):
    """`nohup qlap run …`: SIGHUP ignored when the run starts stays ignored (the terminal may
    close); SIGTERM still stops it between two steps with its outputs."""
    import signal
    import time

    out = tmp_path / "run"
    qlap = str(Path(sys.executable).parent / "qlap")
    p = subprocess.Popen([qlap, "run", "--headless", "--placement", placement, "--world", WORLD,
                          "--steps", "1000000", "--out", str(out), "--quiet"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: (as_in_a_terminal(),
                                             signal.signal(signal.SIGHUP, signal.SIG_IGN)))
    try:
        deadline = time.monotonic() + 120
        while not has_a_line(out / "metrics.jsonl") and time.monotonic() < deadline:
            time.sleep(0.1)                 # the run has taken steps (the file comes first)
        lines = len((out / "metrics.jsonl").read_text().splitlines())
        p.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 120          # the run goes on: its log grows after it
        while (len((out / "metrics.jsonl").read_text().splitlines()) < lines + 3
               and time.monotonic() < deadline):
            assert p.poll() is None, p.communicate()[1]
            time.sleep(0.1)
        assert p.poll() is None, p.communicate()[1]
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        p.kill()
        p.communicate()
    assert p.returncode == 130, err
    assert (out / "checkpoints" / "final" / "agent.json").is_file()


def test_only_the_signals_not_ignored_are_heeded():
    import signal

    from qlap_runtime.runtime.interrupt import heeded, stop_on_signals

    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGHUP)}
    signal.signal(signal.SIGINT, signal.default_int_handler)   # as in a terminal
    signal.signal(signal.SIGHUP, signal.SIG_IGN)               # as under nohup
    try:
        assert heeded((signal.SIGINT, signal.SIGHUP)) == (signal.SIGINT,)
        with stop_on_signals((signal.SIGINT, signal.SIGHUP)):
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@pytest.mark.parametrize(("placement", "quiet"), [("sync", False), ("embedded", False),
                                                  ("sync", True), ("embedded", True)])
def test_a_reader_that_leaves_stops_the_printing_not_the_run(tmp_path, placement, quiet):
    """`qlap run … | head -1`: the progress lines (or, with --quiet, the report at the end)
    stop when the pipe closes; the run goes on to its last step, writes its outputs and does
    not call itself failed."""
    out = tmp_path / "run"
    qlap = str(Path(sys.executable).parent / "qlap")
    p = subprocess.Popen([qlap, "run", "--headless", "--placement", placement, "--world", WORLD,
                          "--steps", "12000", "--out", str(out)] + (["--quiet"] if quiet else []),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert p.stdout is not None
    p.stdout.readline()
    p.stdout.close()                                     # the reader leaves
    _, err = p.communicate(timeout=300)
    assert p.returncode in (0, 141), err.decode()
    assert "Broken pipe" not in err.decode() and "no checkpoint" not in err.decode()
    assert json.loads((out / "summary.json").read_text())["steps"] == 12000
    assert (out / "checkpoints" / "final").exists()
    assert (out / "metrics.png").is_file()
