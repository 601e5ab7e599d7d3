"""A learner's batches in a worker process, off the step chain's GIL (docs/decisions.md 80).

The batch at step t (Algorithm 2 lines 6–13) runs on a private copy of the learner
(:func:`~.batches.copy_for_batch`). In a process of its own it would hold the GIL of the actors
that share it for the whole computation; :class:`BatchProcess` sends the copy instead to a child
process (``python -m qlap_runtime.runtime.batch_process``) as the checkpoint's own state —
:func:`~qlap_runtime.qlap.checkpoint.learner_state`'s JSON object and arrays, the arrays as raw
bytes after a JSON header (no pickle) — and the child, which rebuilds it with
:func:`~qlap_runtime.qlap.checkpoint.restore_learner` (what ``--resume`` does, exact),
computes the parts and answers them as the deltas' JSON. The caller's thread waits in the
pipe's reads and writes with the GIL released.

Frame: 8 bytes (big-endian length of the header), the header (UTF-8 JSON), then each array
of the header's ``arrays`` list (``[name, dtype, shape]``) as its C-order bytes.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading
import time
from typing import IO, Any

import numpy as np

from ..qlap.checkpoint import learner_state, restore_learner
from ..qlap.delta import Delta
from ..qlap.learner import ModelLearner

LENGTH = struct.Struct(">Q")


ENV = "QLAP_BATCH_PROCESS"
"""Set to ``1``, the embedded placement's handed batches compute in a worker process (off by
default: it costs ~270 MiB for core, docs/decisions.md 80)."""


def wanted() -> bool:
    """Whether the run asks for the batch worker process (:data:`ENV`)."""
    return os.environ.get(ENV) == "1"


class BatchProcessError(RuntimeError):
    """The worker process failed or died (its message says why)."""


def write_frame(out: IO[bytes], header: dict[str, Any],
                arrays: dict[str, np.ndarray] | None = None) -> None:
    """``header`` and ``arrays`` (listed in the header's ``arrays``) as one frame."""
    items = [(k, np.asarray(v, order="C")) for k, v in (arrays or {}).items()]
    for k, v in items:
        if v.dtype.hasobject:
            raise TypeError(f"array {k!r} holds Python objects")
    head = json.dumps({**header, "arrays": [[k, v.dtype.str, list(v.shape)]
                                            for k, v in items]}).encode()
    out.write(LENGTH.pack(len(head)) + head)
    for _, v in items:
        if v.size:
            out.write(memoryview(v.reshape(-1)).cast("B"))
    out.flush()


def _read_exact(inp: IO[bytes], n: int) -> bytes | bytearray:
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = inp.readinto(view[got:])            # type: ignore[attr-defined]
        if not k:
            raise EOFError(f"frame cut after {got} of {n} bytes")
        got += k
    return buf


def read_frame(inp: IO[bytes]) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
    """The next frame (None at the end of the stream)."""
    first = inp.read(LENGTH.size)
    if not first:
        return None
    if len(first) < LENGTH.size:
        raise EOFError("frame cut in its length")
    header = json.loads(bytes(_read_exact(inp, LENGTH.unpack(first)[0])))
    arrays: dict[str, np.ndarray] = {}
    for name, dtype, shape in header.pop("arrays"):
        dt = np.dtype(dtype)
        if dt.hasobject:
            raise ValueError(f"array {name!r}: dtype {dtype} holds Python objects")
        n = dt.itemsize * int(np.prod(shape, dtype=np.int64))
        arrays[name] = np.frombuffer(_read_exact(inp, n), dtype=dt).reshape(shape)
    return header, arrays


class BatchProcess:
    """One worker process for a run's batches; :meth:`compute` is called from worker threads
    (one batch at a time) and :meth:`close` ends the process."""

    def __init__(self) -> None:
        # This process's code (-P: not the working directory's tree before it).
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        self.proc = subprocess.Popen(
            [sys.executable, "-P", "-m", "qlap_runtime.runtime.batch_process"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self.lock = threading.Lock()
        self.times: list[float] = []
        """Each batch's time in the worker (rebuilding the copy and computing)."""
        self.peak_mib: float | None = None
        """The worker's peak resident memory, read at :meth:`close` (Linux)."""

    def compute(self, work: ModelLearner, step: int,
                kinds: tuple[str, ...]) -> dict[str, Delta]:
        """``work.compute_parts(step, kinds)``, computed by the worker on a rebuilt ``work``
        (left as it is here)."""
        meta, arrays = learner_state(work)
        with self.lock:
            try:
                assert self.proc.stdin is not None
                assert self.proc.stdout is not None
                write_frame(self.proc.stdin, {"step": step, "kinds": list(kinds),
                                              "meta": meta}, arrays)
                answer = read_frame(self.proc.stdout)
            except (OSError, EOFError, ValueError) as exc:
                raise BatchProcessError(f"batch worker at step {step}: {exc}") from None
        if answer is None:
            raise BatchProcessError(f"batch worker ended at step {step} "
                                    f"(exit code {self.proc.poll()})")
        header = answer[0]
        if "error" in header:
            raise BatchProcessError(f"batch worker at step {step}: {header['error']}")
        self.times.append(float(header["compute_s"]))
        return {k: Delta.from_json(v) for k, v in header["parts"].items()}

    def close(self) -> None:
        """End the worker (its input closes; it exits at the end of the stream)."""
        self.peak_mib = self.peak_mib or peak_mib(self.proc.pid)
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def peak_mib(pid: int) -> float | None:
    """A live process's peak resident memory (``VmHWM``), None where /proc has none."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    return None


def serve(inp: IO[bytes], out: IO[bytes]) -> None:
    """The worker's loop: a batch request per frame, the parts' JSON per answer."""
    from ..qlap.kernels import kernels
    kernels()                                   # loaded before the first batch needs them
    while (frame := read_frame(inp)) is not None:
        header, arrays = frame
        t0 = time.perf_counter()
        try:
            work = restore_learner(header["meta"], arrays)
            parts = work.compute_parts(int(header["step"]), tuple(header["kinds"]))
            answer: dict[str, Any] = {"parts": {k: d.to_json() for k, d in parts.items()},
                                      "compute_s": time.perf_counter() - t0}
        except Exception as exc:                # answered: the caller raises it
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        write_frame(out, answer)


if __name__ == "__main__":                      # pragma: no cover - run by BatchProcess
    serve(sys.stdin.buffer, sys.stdout.buffer)
