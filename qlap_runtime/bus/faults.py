"""Injected message faults, for tests and the chaos harness only (docs/runtime.md, Faults).

A :class:`Faults` plan (``RunContext.faults``, JSON) makes a :class:`~.bridge.Publisher` of a
chosen topic drop a fraction of its messages and delay another fraction by ``delay_s``
seconds (put later from a timer thread, so they arrive out of order), as a lossy or congested
network would. The writer still logs every message in its replay log (the loss happens on the
way), so a lockstep consumer recovers by asking the replay log again
(:mod:`~qlap_runtime.runtime.inbox`); what it cannot recover the watchdog reports.

Nothing here runs unless a plan is given: a normal run has ``faults`` None and its publishers
put directly.
"""

from __future__ import annotations

import logging
import threading
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

log = logging.getLogger("qlap.bus")

FAULT_TOPICS = ("sense", "qstate", "motor", "delta/dbn", "delta/landmarks", "batchctx",
                "planreq", "delta/plans")
"""The topics a plan may name: the lockstep chain and the learners' inputs (each kept in a
replay log by its writer). Not ``control``: its commands and the world's end marker after a
``quit`` have no replay log, so a lost one cannot be asked for again (a consumer left waiting
for a step after the end is the watchdog's case)."""


class FaultsError(ValueError):
    """A malformed fault plan."""


@dataclass(frozen=True)
class Faults:
    """What to inject: each message of ``topics`` is dropped with probability ``drop``, else
    delayed by ``delay_s`` with probability ``delay``; ``seed`` makes the draws repeatable
    (per actor and topic); ``lost``: see below."""

    drop: float = 0.0
    delay: float = 0.0
    delay_s: float = 0.2
    topics: tuple[str, ...] = FAULT_TOPICS
    seed: int = 0
    lost: bool = False
    """A dropped message is missing from the writer's replay log too (nothing can recover
    it: the case the watchdog reports)."""

    def __post_init__(self) -> None:
        for name in ("drop", "delay"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise FaultsError(f"faults: {name} must be a probability in [0, 1], got {v}")
        if self.drop + self.delay > 1.0:
            raise FaultsError("faults: drop + delay must not exceed 1")
        if not 0.0 <= self.delay_s <= 60.0:
            raise FaultsError(f"faults: delay_s must be in [0, 60] seconds, got "
                              f"{self.delay_s}")
        unknown = sorted(set(self.topics) - set(FAULT_TOPICS))
        if unknown:
            raise FaultsError(f"faults: unknown topics {unknown}; known: "
                              f"{', '.join(FAULT_TOPICS)}")

    @classmethod
    def of(cls, d: dict[str, Any] | None) -> Faults | None:
        """The plan of ``RunContext.faults`` (None: no faults)."""
        if not d:
            return None
        try:
            kw = dict(d)
            if "topics" in kw:
                kw["topics"] = tuple(str(t) for t in kw["topics"])
            return cls(**kw)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, FaultsError):
                raise
            raise FaultsError(f"faults: {exc}") from None

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["topics"] = list(self.topics)
        return d

    def injector(self, topic: str, tag: str = "") -> FaultInjector | None:
        """The injector of one publisher of ``topic`` (None when the plan spares it)."""
        if topic not in self.topics or (self.drop == 0.0 and self.delay == 0.0):
            return None
        return FaultInjector(self, topic, tag)


class FaultInjector:
    """Drops or delays the puts of one publisher (see :class:`Faults`); counts what it did."""

    def __init__(self, faults: Faults, topic: str, tag: str = "") -> None:
        self.faults, self.topic = faults, topic
        self._rng = np.random.default_rng(
            [faults.seed, zlib.crc32(tag.encode()), zlib.crc32(topic.encode())])
        self.dropped = 0
        self.delayed = 0
        self._closed = False

    def put(self, put: Callable[[bytes], Any], payload: bytes) -> bool:
        """Put ``payload`` with ``put`` now, later, or never (then False)."""
        r = self._rng.random()
        if r < self.faults.drop:
            self.dropped += 1
            return False
        if r < self.faults.drop + self.faults.delay:
            self.delayed += 1
            timer = threading.Timer(self.faults.delay_s, self._late, (put, payload))
            timer.daemon = True
            timer.start()
            return True
        put(payload)
        return True

    @property
    def lost(self) -> bool:
        """Whether a dropped message is kept out of the writer's replay log too."""
        return self.faults.lost

    def _late(self, put: Callable[[bytes], Any], payload: bytes) -> None:
        if self._closed:
            return
        try:
            put(payload)
        except Exception as exc:                # the publisher or session closed meanwhile
            log.debug("delayed put on %s not sent: %s", self.topic, exc)

    def close(self) -> None:
        """No delayed put after this (the publisher is being undeclared)."""
        self._closed = True

    def counts(self) -> dict[str, int]:
        return {"dropped": self.dropped, "delayed": self.delayed}
