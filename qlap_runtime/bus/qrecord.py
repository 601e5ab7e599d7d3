"""``qstate(t)`` as a binary record: the perception actor's wire format (docs/decisions.md 98).

A JSON :class:`~.schema.QState` is built per step as dicts by variable name and encoded by
orjson, and every learner converted it back into arrays: on the hosted step chain that was
~1.2 s of 9–10 s of CPU per 30,000 core steps. A record is the percept's arrays as they are::

    header  <3sBBqHHHH  magic b"\\x00QR", version, flags (1 rejected, 2 discontinuity), step,
                        n variables, n events, names' bytes, reason's bytes
    names   the variable names in table order, UTF-8, joined by NUL (the same bytes for every
            step of a run: a consumer checks its table with one comparison)
    x       n float64, little-endian: real values; NaN where not (yet) available
    q       n int64, little-endian: qualitative values; −1 where unavailable
    events  n_events × 3 int32: (variable index, value, direction ∈ {−1, 0, 1})
    reason  UTF-8: why sense(t) was rejected (a rejected step has no variables, names, events)

No pickle. The first byte (NUL) is never the first byte of a JSON message, so ``qstate``
carries either; :func:`decode_record` validates everything and raises :class:`RecordError`
(:func:`~.schema.decode` makes it a counted :class:`~.schema.MessageError`).
:func:`~.schema.qstate_of` gives the JSON message of the same step (the recorder, ``echo``).
"""

from __future__ import annotations

import base64
import math
import struct
from functools import lru_cache
from typing import Any

import numpy as np

MAGIC = b"\x00QR"
VERSION = 1
HEAD = struct.Struct("<3sBBqHHHH")
REJECTED, DISCONTINUITY = 1, 2
_F8, _I8, _I4 = np.dtype("<f8"), np.dtype("<i8"), np.dtype("<i4")
_NO_EVENTS = np.zeros((0, 3), dtype=_I4)
_NO_EVENTS.flags.writeable = False


class RecordError(ValueError):
    """A payload that is not a valid ``qstate`` record."""


def is_record(payload: Any) -> bool:
    """Whether ``payload`` (bytes-like) starts as a record rather than as JSON."""
    return isinstance(payload, bytes | bytearray | memoryview) and bytes(payload[:3]) == MAGIC


def names_blob(names: tuple[str, ...] | list[str]) -> bytes:
    """The names block of a table's records."""
    if any("\x00" in n for n in names):
        raise ValueError("a variable name holds NUL")
    return "\x00".join(names).encode()


@lru_cache(maxsize=64)
def _names_of(blob: bytes) -> tuple[str, ...]:
    """The names of a block (cached: every record of a run carries the same bytes)."""
    try:
        return tuple(blob.decode().split("\x00")) if blob else ()
    except UnicodeDecodeError as e:
        raise RecordError(f"names are not UTF-8: {e}") from None


class QRecord:
    """One ``qstate(t)`` record: its payload, its header, and its arrays read from the payload
    when first asked for (read-only views of the immutable payload, so a record never changes
    after it is made; the writer on the step chain never asks)."""

    __slots__ = ("_arrays", "discontinuity", "n", "names_blob", "ne", "payload", "rejected",
                 "step")

    version = VERSION

    def __init__(self, payload: bytes, step: int, n: int, ne: int, names: bytes,
                 rejected: str = "", discontinuity: bool = False) -> None:
        """Use :func:`encode_record`, :func:`encode_rejected` or :func:`decode_record`."""
        self.payload, self.step, self.n, self.ne, self.names_blob = payload, step, n, ne, names
        self.rejected, self.discontinuity = rejected, discontinuity
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._arrays is None:
            data, n, ne = self.payload, self.n, self.ne
            at = HEAD.size + len(self.names_blob)
            x = np.frombuffer(data, _F8, n, at)
            q = np.frombuffer(data, _I8, n, at + 8 * n)
            ev = np.frombuffer(data, _I4, 3 * ne, at + 16 * n).reshape(ne, 3) if ne \
                else _NO_EVENTS
            self._arrays = (x, q, ev)
        return self._arrays

    @property
    def x(self) -> np.ndarray:
        """Real values by variable index, NaN where not available (read-only)."""
        return self._read()[0]

    @property
    def q(self) -> np.ndarray:
        """Qualitative values by variable index, −1 where unavailable (read-only)."""
        return self._read()[1]

    @property
    def events(self) -> np.ndarray:
        """The events as rows (variable index, value, direction) (read-only)."""
        return self._read()[2]

    @property
    def names(self) -> tuple[str, ...]:
        """The variable names in table order (empty for a rejected step)."""
        return _names_of(self.names_blob)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, QRecord) and other.payload == self.payload

    def __hash__(self) -> int:
        return hash(self.payload)

    def __repr__(self) -> str:
        what = f"rejected={self.rejected!r}" if self.rejected else \
            f"{self.n} variables, {self.ne} events"
        return f"QRecord(step={self.step}, {what}, discontinuity={self.discontinuity})"


def encode_record(step: int, blob: bytes, x: np.ndarray, q: np.ndarray, events: Any = (),
                  discontinuity: bool = False) -> QRecord:
    """The record of a percept: ``blob`` from :func:`names_blob`, ``x`` and ``q`` by variable
    index, ``events`` as (variable, value, direction) triples."""
    n, ne = len(x), len(events)
    ev = struct.pack(f"<{3 * ne}i", *[v for e in events for v in e]) if ne else b""
    payload = b"".join((HEAD.pack(MAGIC, VERSION, DISCONTINUITY if discontinuity else 0,
                                  step, n, ne, len(blob), 0), blob,
                        x.astype(_F8, copy=False).tobytes(),
                        q.astype(_I8, copy=False).tobytes(), ev))
    return QRecord(payload, step, n, ne, blob, "", discontinuity)


def encode_rejected(step: int, reason: str) -> QRecord:
    """The record of a rejected step: no variables, the reason (not empty)."""
    why = reason or "rejected"
    raw = why.encode()
    return QRecord(HEAD.pack(MAGIC, VERSION, REJECTED, step, 0, 0, 0, len(raw)) + raw,
                   step, 0, 0, b"", why)


RECENT = 256
"""Records decoded lately, kept by payload (:func:`decode_record`): the two learners sharing a
process each subscribe to ``qstate`` and get every record, so the second decodes none."""
_recent: dict[bytes, QRecord] = {}


def decode_record(payload: bytes | bytearray | memoryview) -> QRecord:
    """The record ``payload`` holds, validated — its size, flags, names, real values finite or
    NaN, qualitative values ≥ −1, events on known variables with a direction in {−1, 0, 1} —
    else :class:`RecordError`. A payload decoded lately gives the same (immutable) record."""
    data = bytes(payload)
    rec = _recent.get(data)
    if rec is not None:
        return rec
    rec = _decode(data)
    if len(_recent) >= RECENT:
        _recent.clear()
    _recent[data] = rec
    return rec


def _decode(data: bytes) -> QRecord:
    if len(data) < HEAD.size:
        raise RecordError(f"{len(data)} bytes: shorter than the {HEAD.size}-byte header")
    magic, version, flags, step, n, ne, nlen, rlen = HEAD.unpack_from(data)
    if magic != MAGIC:
        raise RecordError("not a qstate record (bad magic)")
    if version != VERSION:
        raise RecordError(f"unknown version {version} (supported: [{VERSION}])")
    if flags & ~(REJECTED | DISCONTINUITY):
        raise RecordError(f"unknown flags {flags:#x}")
    want = HEAD.size + nlen + 16 * n + 12 * ne + rlen
    if len(data) != want:
        raise RecordError(f"{len(data)} bytes, expected {want} (truncated or padded)")
    try:
        reason = data[want - rlen:].decode() if rlen else ""
    except UnicodeDecodeError as e:
        raise RecordError(f"reason is not UTF-8: {e}") from None
    rec = QRecord(data, step, n, ne, data[HEAD.size:HEAD.size + nlen], reason,
                  bool(flags & DISCONTINUITY))
    if flags & REJECTED:
        if not reason or n or ne or nlen:
            raise RecordError("a rejected step carries a reason and nothing else")
        return rec
    if reason:
        raise RecordError("a reason without the rejected flag")
    if len(rec.names) != n:
        raise RecordError(f"{len(rec.names)} names for {n} variables")
    x, q, ev = rec._read()
    if not math.isfinite(sum(x.tolist())) and np.isinf(x).any():  # NaN: not available
        raise RecordError("real values must be finite (NaN: not available)")
    if n and int(np.minimum.reduce(q)) < -1:
        raise RecordError(f"qualitative value {int(np.minimum.reduce(q))} below −1")
    for var, value, direction in ev.tolist():
        if not 0 <= var < n or value < 0 or direction not in (-1, 0, 1):
            raise RecordError(f"malformed event {(var, value, direction)!r} "
                              f"({n} variables)")
    return rec


def payload_text(payload: bytes) -> str:
    """A logged payload as text for a snapshot's JSON: a JSON message as it is, a record as
    ``base64:`` and its base64 (:func:`payload_bytes` reverses it)."""
    if is_record(payload):
        return "base64:" + base64.b64encode(payload).decode()
    return payload.decode()


def payload_bytes(text: str) -> bytes:
    """The payload :func:`payload_text` wrote."""
    if text.startswith("base64:"):
        return base64.b64decode(text[7:], validate=True)
    return text.encode()
