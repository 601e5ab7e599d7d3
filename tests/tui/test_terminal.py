"""``qlap run`` in a real terminal, the way ``scripts/run`` starts it (issue 12).

The other UI tests drive :class:`~tui.QlapApp` with Textual's pilot on a driver they build
themselves; this one runs the ``qlap`` command (no ``--headless``, no placement, no
``--babble-steps``) on a pseudo-terminal, so that the command line, ``run_tui``, the agent
process (spawn) and the UI are all exercised together: it waits until the panels show the
agent stepping, presses ``q`` and expects a clean exit.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pty
import re
import shutil
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs a POSIX pty")

COLUMNS, ROWS = 120, 36
START_TIMEOUT = 120.0
"""Until the panels show the agent stepping (imports, spawn and a world on a loaded box)."""
EXIT_TIMEOUT = 30.0
"""From ``q`` to the end of the process (the UI closes, then the agent process stops)."""

_ESCAPES = re.compile(rb"\x1b\[[0-?]*[ -/]*[@-~]|\x1b[()][0-9A-Za-z]|\x1b[=>78]|\x1b\][^\x07]*\x07")
_STEP = re.compile(r"RUNNING\s+step\s+(\d+)")


def _qlap_command() -> list[str]:
    """The console script ``scripts/run`` execs (``$VENV/bin/qlap run``)."""
    script = Path(sys.executable).with_name("qlap")
    if script.exists():
        return [str(script)]
    found = shutil.which("qlap")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; from qlap_runtime.cli import main; "
                                  "sys.exit(main())"]


class Terminal:
    """A child process on a pseudo-terminal; a thread keeps draining what it writes."""

    def __init__(self, argv: list[str], cwd: Path, columns: int, rows: int) -> None:
        master, slave = pty.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
        env = {k: v for k, v in os.environ.items()
               if not k.startswith(("TEXTUAL", "PYTEST")) and k not in ("COLUMNS", "LINES")}
        env.update(TERM="xterm-256color", COLORTERM="truecolor", PYTHONUNBUFFERED="1")
        self.master = master
        self._buf = bytearray()
        self._lock = threading.Lock()
        try:
            self.proc = subprocess.Popen(argv, cwd=cwd, env=env, stdin=slave, stdout=slave,
                                         stderr=slave, start_new_session=True, close_fds=True)
        except BaseException:
            os.close(master)
            raise
        finally:
            os.close(slave)
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()

    def _drain(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 65536)
            except OSError:            # EIO: every slave end is closed (the child ended)
                return
            if not chunk:
                return
            with self._lock:
                self._buf += chunk

    def raw(self) -> bytes:
        with self._lock:
            return bytes(self._buf)

    def text(self) -> str:
        """Everything written so far, without escape sequences."""
        return _ESCAPES.sub(b"", self.raw()).decode("utf-8", "replace")

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def tail(self, n: int = 3000) -> str:
        return self.text()[-n:]

    def close(self) -> None:
        """Kill the whole process group (the UI and the agent process) if still running."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        # The agent process may outlive the UI process by a moment: take it down too.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self._reader.join(5)
        os.close(self.master)


def _steps_seen(text: str) -> list[int]:
    return [int(n) for n in _STEP.findall(text)]


@pytest.mark.timeout(START_TIMEOUT + EXIT_TIMEOUT + 60)
def test_qlap_run_in_a_terminal_opens_the_ui_runs_the_agent_and_quits_on_q(tmp_path):
    argv = [*_qlap_command(), "run", "--world", "core2d"]
    term = Terminal(argv, cwd=tmp_path, columns=COLUMNS, rows=ROWS)
    try:
        # 1. The panels fill: titles drawn, then the runtime panel shows the agent stepping.
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            text = term.text()
            steps = _steps_seen(text)
            if ("Runtime" in text and "Counters" in text and len(set(steps)) >= 2
                    and max(steps) > min(steps) and max(steps) > 0):
                break
            code = term.proc.poll()
            assert code is None, (f"`{' '.join(argv)}` exited with code {code} before the "
                                  f"UI showed the agent running:\n{term.tail()}")
            assert time.monotonic() < deadline, (
                f"the UI did not show the agent stepping within {START_TIMEOUT:.0f} s:\n"
                f"{term.tail()}")
            time.sleep(0.2)
        assert "Traceback" not in text, term.tail()

        # 2. q quits: the UI closes, the agent process stops, the command exits with 0.
        term.send(b"q")
        try:
            code = term.proc.wait(EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.fail(f"`q` did not end `qlap run` within {EXIT_TIMEOUT:.0f} s:\n"
                        f"{term.tail()}")
        term._reader.join(5)
        after_quit = term.text()
        assert code == 0, f"`qlap run` exited with code {code}:\n{term.tail()}"
        assert "Traceback" not in after_quit, term.tail()
        assert "did not start" not in after_quit, term.tail()
        assert "stopping the agent" in after_quit, term.tail()   # quit mid-run: it saves
    finally:
        term.close()


@pytest.mark.timeout(START_TIMEOUT + EXIT_TIMEOUT + 60)
def test_quitting_a_finished_run_says_nothing_about_stopping_it(tmp_path):
    argv = [*_qlap_command(), "run", "--world", "core2d", "--steps", "200"]
    term = Terminal(argv, cwd=tmp_path, columns=COLUMNS, rows=ROWS)
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while "FINISHED" not in term.text():
            assert term.proc.poll() is None, term.tail()
            assert time.monotonic() < deadline, f"no FINISHED:\n{term.tail()}"
            time.sleep(0.2)
        time.sleep(1.0)                         # the UI's status of the last step
        term.send(b"q")
        code = term.proc.wait(EXIT_TIMEOUT)
        term._reader.join(5)
        text = term.text()
        assert code == 0, term.tail()
        assert "wrote " in text and "stopping the agent" not in text, term.tail()
        # summary.json names the UI's runner (as its Runtime panel does), not an actor placement.
        (summary,) = tmp_path.glob("runs/*/summary.json")
        assert json.loads(summary.read_text())["placement"] == "local"
    finally:
        term.close()


def _wait_running(term: Terminal, argv: list[str]) -> None:
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        text = term.text()
        steps = _steps_seen(text)
        if "Runtime" in text and len(set(steps)) >= 2 and max(steps) > min(steps):
            return
        assert term.proc.poll() is None, f"`{' '.join(argv)}` ended:\n{term.tail()}"
        assert time.monotonic() < deadline, f"the agent did not step:\n{term.tail()}"
        time.sleep(0.2)


@pytest.mark.timeout(START_TIMEOUT + EXIT_TIMEOUT + 60)
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGKILL"])
def test_a_killed_ui_leaves_an_agent_that_writes_its_outputs_and_ends(tmp_path, sig):
    """`kill` of the UI's process (SIGTERM: it quits as `q` does; SIGKILL: the agent process
    notices its parent is gone) never leaves an agent running: the outputs are written and
    every process of the run ends."""
    argv = [*_qlap_command(), "run", "--world", "core2d", "--steps", "100000000"]
    term = Terminal(argv, cwd=tmp_path, columns=COLUMNS, rows=ROWS)
    try:
        _wait_running(term, argv)
        os.kill(term.proc.pid, getattr(signal, sig))
        term.proc.wait(EXIT_TIMEOUT)                  # the UI's process ends (reaped here)
        for _ in range(int(EXIT_TIMEOUT / 0.2)):     # the agent's outputs, final the last
            if list(tmp_path.rglob("checkpoints/final")):
                break
            time.sleep(0.2)
        summary = list(tmp_path.rglob("summary.json"))
        assert summary, f"no outputs within {EXIT_TIMEOUT:.0f} s after {sig}:\n{term.tail()}"
        assert (summary[0].parent / "knowledge.json").is_file()
        assert (summary[0].parent / "checkpoints" / "final").exists()
        for _ in range(int(EXIT_TIMEOUT / 0.2)):     # and the agent's process too
            try:
                os.killpg(term.proc.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.2)
        else:
            pytest.fail(f"a process of the run is still alive {EXIT_TIMEOUT:.0f} s after {sig}")
    finally:
        term.close()
