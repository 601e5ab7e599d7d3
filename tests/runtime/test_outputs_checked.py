"""Outputs are checked before the run in every placement, a write failure stops a processes run
with one line in bounded time (it used to hang: the restarted executor waited for writers that
had exited), and a SIGKILLed launcher's temporary directory is removed at the next start
(issue 13, items 3 and 6)."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from qlap_runtime.placements.launcher import (
    OWNER_FILE,
    RUN_DIR_PREFIX,
    remove_stale_run_dirs,
    run_embedded,
)
from qlap_runtime.runtime.outputs import OutputError, check_out

from ..actors.test_faults import BASE, context


@pytest.fixture
def tiny_fs(tmp_path):
    """A real 40 MB tmpfs (root and mount(2) needed). Only a non-root user is skipped: as
    root (this project's CI) a failed mount fails the test, so that the full-disk checks
    cannot go quietly unrun."""
    mnt = tmp_path / "fs"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode:
        if os.geteuid() == 0:
            pytest.fail(f"root cannot mount a tmpfs here: {r.stderr.strip()}")
        pytest.skip(f"not root: cannot mount a tmpfs ({r.stderr.strip()})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def fill(fs: Path, leave: int = 0) -> int:
    """Write a ballast file until the filesystem is full (less ``leave`` bytes)."""
    n = 0
    with open(fs / "ballast", "wb") as f:
        chunk = b"\1" * 2**20
        try:
            while True:
                free = os.statvfs(fs).f_bavail * os.statvfs(fs).f_frsize
                if free <= leave:
                    break
                n += f.write(chunk[:max(1, min(len(chunk), free - leave))])
                f.flush()
        except OSError:
            pass
    return n


class FillAt:
    """A thread that fills ``fs`` once the run's metrics.jsonl reaches ``step`` and the
    checkpoint ``after`` (if given) is whole — it is written off the loop, and on a loaded
    machine may still be in flight at ``step``; ``at`` is when it did (None before),
    :meth:`stop` ends it."""

    def __init__(self, fs: Path, out: Path, step: int, poll_s: float = 0.05,
                 after: Path | None = None) -> None:
        self.at: float | None = None
        self._stop = threading.Event()

        def run() -> None:
            while not self._stop.is_set() and self.at is None:
                try:
                    rows = (out / "metrics.jsonl").read_text().splitlines()
                except OSError:
                    rows = []
                whole = after is None or (after / "agent.json").is_file()
                if rows and json.loads(rows[-1]).get("step", 0) >= step and whole:
                    fill(fs)
                    self.at = time.monotonic()
                time.sleep(poll_s)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def test_check_out_refuses_a_full_disk_and_a_file(tiny_fs, tmp_path):
    fill(tiny_fs, leave=8 * 2**20)
    with pytest.raises(OutputError, match=r"MB free, a run needs at least 32 MB"):
        check_out(tiny_fs / "runs" / "run")
    assert not (tiny_fs / "runs").exists()            # the directories it made are gone
    (tiny_fs / "mine").mkdir()
    with pytest.raises(OutputError, match=r"MB free"):
        check_out(tiny_fs / "mine")
    assert (tiny_fs / "mine").is_dir()                 # one that was there stays
    check_out(tiny_fs / "run2", min_free=4 * 2**20)          # 8 MB left: enough for 4
    afile = tmp_path / "f"
    afile.write_text("")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        check_out(afile)


def test_embedded_checks_the_run_directory_before_starting(tiny_fs):
    fill(tiny_fs, leave=2**20)
    ctx = context(tiny_fs / "run", BASE, 7, "t-out-emb")
    t0 = time.monotonic()
    with pytest.raises(OutputError, match="1.0 MB free|0.9 MB free"):
        run_embedded(ctx)
    assert time.monotonic() - t0 < 5                         # refused before anything ran


def test_a_disk_full_at_the_end_of_a_processes_run_is_one_line_in_bounded_time(tiny_fs):
    """The disk fills after step 2,000: the executor cannot write its metrics or
    knowledge.json, nor the world and contingency actors their parts of the final checkpoint
    (whichever writes first is named): the run stops (no restart, no hang) with one line;
    metrics.jsonl, written before, stays. The run is 6,000 steps long so that it cannot end
    before the filler's poll sees step 2,000 (a 3,000-step run whose learners keep up did,
    docs/decisions.md 90–92)."""
    out = tiny_fs / "run"
    metrics = out / "metrics.jsonl"
    filler = FillAt(tiny_fs, out, 2000)
    proc = subprocess.Popen([sys.executable, "-m", "qlap_runtime.cli", "run", "--headless",
                             "--quiet", "--placement", "processes", "--world", "core2d",
                             "--steps", "6000", "--babble-steps", "1500", "--lag", "200",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    _, stderr = proc.communicate(timeout=240)
    end = time.monotonic()
    left = group_members(proc.pid)                          # its own process group
    r = subprocess.CompletedProcess(proc.args, proc.returncode, "", stderr)
    filler.stop()
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in lines[-1]
    # The default process groups: "process world+perception+executor+planner (actors …)".
    assert re.match(r"qlap run: (actor (executor|contingency|world)|process [a-z+]+ "
                    r"\(actors [a-z, ]+\)) exited with code 1 \(OSError: ", lines[-1]), lines[-1]
    assert "No space left on device" in lines[-1]
    assert "a restart cannot help: run stopped; " in lines[-1]
    # what the run keeps, when a checkpoint was whole before the disk filled, or that none was
    assert re.search(r"; (kept: \S+/checkpoints/step-\d{7} \(go on from it: qlap run "
                     r"--resume \S+ --out NEW_DIR\)|no checkpoint was kept)$", lines[-1]), \
        lines[-1]
    assert filler.at is not None and end - filler.at < 60
    assert len(metrics.read_text().splitlines()) >= 2       # what was written stays
    assert not (out / "knowledge.json").exists()
    assert left == [], f"processes left in the launcher's group: {left}"


def group_members(pgid: int) -> list[str]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if int(fields[2]) == pgid:              # pgrp
                out.append(f"{d.name} {stat.split(' (', 1)[1].split(')')[0]} {fields[0]}")
    return out


def _exit_now() -> None:
    pass


def test_stale_launcher_directories_are_removed_at_the_next_start(tmp_path):
    p = mp.get_context("spawn").Process(target=_exit_now)
    p.start()
    p.join()
    dead, alive, bare = (tmp_path / f"{RUN_DIR_PREFIX}{n}" for n in ("dead", "alive", "bare"))
    for d, pid in ((dead, p.pid), (alive, os.getpid())):
        (d / "snapshots" / "executor").mkdir(parents=True)
        (d / OWNER_FILE).write_text(f"{pid}\n")
    bare.mkdir()
    assert remove_stale_run_dirs(tmp_path) == [dead]
    assert not dead.exists() and alive.exists() and bare.exists()
    old = time.time() - 2 * 86400
    os.utime(bare, (old, old))
    assert remove_stale_run_dirs(tmp_path) == [bare]


@pytest.mark.parametrize("placement", ["sync", "embedded"])
def test_a_disk_full_mid_run_leaves_only_whole_checkpoints_and_names_the_last(tiny_fs,
                                                                               placement):
    """The disk fills after step 12,000: the run stops with one line that names its newest
    whole checkpoint and how to go on from it; no other checkpoint directory is left (an
    actor's part of a checkpoint whose agent was never written is removed), no temporary
    directory, and the kept checkpoint resumes."""
    out = tiny_fs / "run"
    filler = FillAt(tiny_fs, out, 12_000, poll_s=0.02,
                    after=out / "checkpoints" / "step-0010000")
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "run", "--headless",
                        "--quiet", "--placement", placement, "--world", "core", "--steps",
                        "40000", "--out", str(out)], capture_output=True, text=True,
                       timeout=300)
    filler.stop()
    assert filler.at is not None
    last = r.stderr.strip().splitlines()[-1]
    kept = out / "checkpoints" / "step-0010000"
    assert r.returncode == 1, r.stderr
    assert last == (f"qlap run: [Errno 28] No space left on device (run directory {out}); "
                    f"kept: {kept} (go on from it: qlap run --resume {kept} --out NEW_DIR)")
    left = sorted((out / "checkpoints").iterdir())
    assert left == [kept]
    assert (kept / "world.json").is_file()
    (tiny_fs / "ballast").unlink()
    r = subprocess.run([sys.executable, "-m", "qlap_runtime.cli", "run", "--headless",
                        "--quiet", "--placement", "sync", "--resume", str(kept), "--steps",
                        "200", "--out", str(tiny_fs / "on")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
