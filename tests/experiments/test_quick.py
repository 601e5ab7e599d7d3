"""Every experiment end to end with --quick (slow: minutes), and a sweep killed mid-way that
continues without recomputing what it had finished."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from qlap_runtime.cli import main
from qlap_runtime.experiments.registry import EXPERIMENTS, get
from qlap_runtime.experiments.spec import configure
from qlap_runtime.experiments.sweep import plan, run_done

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """One output root for all of them: the QLAP core runs are shared, as in a real use."""
    return tmp_path_factory.mktemp("experiments")


@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_quick(name, root, capsys):
    assert main(["experiment", name, "--quick", "--out", str(root), "--no-live"]) == 0
    out = root / f"{name}-quick"
    page = (out / "RESULTS.md").read_text()
    assert f"qlap experiment {name} --quick" in page and "Quick preset" in page
    exp = get(name)
    for task in exp.tasks:
        assert (out / f"{task}.png").is_file()
    if "dbn_count" in exp.figures:
        assert (out / "dbn-count.png").is_file()
    sweep = plan(configure(exp, quick=True), root)
    assert all(run_done(sweep.run_dir(k), s) for k, s in sweep.runs.items())
    # a second time: nothing to do
    assert main(["experiment", name, "--quick", "--out", str(root), "--no-live"]) == 0
    assert "0 agent runs (" in capsys.readouterr().out.splitlines()[-2]


def test_a_killed_sweep_continues(tmp_path):
    cmd = [sys.executable, "-m", "qlap_runtime.cli", "experiment", "landmarks-vs-random",
           "--quick", "--out", str(tmp_path), "--no-live", "--jobs", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    sweep = plan(configure(get("landmarks-vs-random"), quick=True), tmp_path)
    deadline = time.time() + 300
    try:
        while time.time() < deadline:
            done = [k for k, s in sweep.runs.items() if run_done(sweep.run_dir(k), s)]
            if done:
                break
            assert proc.poll() is None, "the sweep ended before it could be killed"
            time.sleep(0.2)
        else:
            pytest.fail("no run finished in time")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)                   # the sweep and its workers
        proc.wait()
    assert len(done) < len(sweep.runs)
    before = {k: (sweep.run_dir(k) / "summary.json").stat().st_mtime_ns for k in done}
    assert main(["experiment", "landmarks-vs-random", "--quick", "--out", str(tmp_path),
                 "--no-live"]) == 0
    for k, mtime in before.items():                           # finished runs were reused
        assert (sweep.run_dir(k) / "summary.json").stat().st_mtime_ns == mtime
    assert all(run_done(sweep.run_dir(k), s) for k, s in sweep.runs.items())
    tests = json.loads((tmp_path / "landmarks-vs-random-quick" / "experiment.json")
                       .read_text())
    assert tests["name"] == "landmarks-vs-random"
