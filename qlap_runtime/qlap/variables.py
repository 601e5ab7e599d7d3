"""QLAP's qualitative variables and the events on them (ch. 3, Table 3.1, Appendix A).

From a world's variable table QLAP builds: a motor variable per motor, a magnitude variable and a
derived direction-of-change variable (named ``<name>.dot``) per magnitude input, and a nominal
variable per nominal input. Variables are numbered in that order; the numbering never changes
during a run (variables that appear later, §7.5, are simply unavailable until then).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

DOT = ".dot"
CHANGE_LABELS = ("-", "0", "+")
"""Labels of the three values [-], [0], [+] of a direction-of-change variable (§3.1)."""


class Kind(enum.StrEnum):
    """The kinds of qualitative variable (Table 3.1 and Appendix A)."""

    MOTOR = "motor"
    MAGNITUDE = "magnitude"
    CHANGE = "change"
    NOMINAL = "nominal"


@dataclass(frozen=True)
class QVar:
    """One qualitative variable."""

    index: int
    """Position in the agent's variable vector."""
    name: str
    """World name, or ``<magnitude>.dot`` for a direction-of-change variable."""
    kind: Kind
    """Motor, magnitude, direction of change or nominal."""
    values: tuple[str, ...] = ()
    """Nominal labels (the observation carries the index)."""
    low: float | None = None
    """Motor range (motor actions draw within it, §5.5)."""
    high: float | None = None
    """Motor range."""
    available_from: int = 0
    """First step at which the world reports the variable (transfer, §7.5)."""
    source: int = -1
    """For a change variable, the index of its magnitude variable; else −1."""
    resolution: float | None = None
    """Motors and magnitudes: the world's resolution (no landmark narrower or closer), or None
    for the agent's default (``Perception.resolution``)."""


class Event(NamedTuple):
    """The event X → x (§3.2); ``direction`` is +1 for ↑, −1 for ↓ on magnitudes, else 0."""

    var: int
    value: int
    direction: int = 0

    # Immutable: a copy (e.g. a batch's deep copy of a learner, whose DBNs, indexes and pairs
    # hold thousands of events) is the event itself (docs/decisions.md 101).
    def __copy__(self) -> Event:
        return self

    def __deepcopy__(self, memo: dict) -> Event:
        return self


@dataclass
class VariableTable:
    """All qualitative variables of an agent, in a fixed order."""

    vars: list[QVar] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.by_name = {v.name: v for v in self.vars}

    @classmethod
    def from_specs(cls, specs: Iterable[Any]) -> VariableTable:
        """Build from world variable specs (objects with name, kind, values, low, high).

        ``kind`` may be an enum with a ``value`` or a string: motor / magnitude / nominal.
        """
        motors, mags, noms = [], [], []
        seen: set[str] = set()
        for s in specs:
            kind = getattr(s.kind, "value", s.kind)
            if s.name in seen:
                raise ValueError(f"duplicate variable name {s.name!r}")
            if s.name.endswith(DOT):
                raise ValueError(f"variable name {s.name!r} may not end with {DOT!r}")
            seen.add(s.name)
            bucket = {"motor": motors, "magnitude": mags, "nominal": noms}.get(kind)
            if bucket is None:
                raise ValueError(f"variable {s.name!r} has unknown kind {kind!r}; "
                                 "expected motor, magnitude or nominal")
            bucket.append(s)
        out: list[QVar] = []
        for s in motors:
            if s.low is None or s.high is None or not s.low < s.high:
                raise ValueError(f"motor {s.name!r} needs a range low < high, got "
                                 f"[{s.low}, {s.high}]")
            out.append(QVar(len(out), s.name, Kind.MOTOR, low=float(s.low), high=float(s.high),
                            available_from=int(getattr(s, "available_from", 0)),
                            resolution=_resolution(s)))
        mag_index: dict[str, int] = {}
        for s in mags:
            mag_index[s.name] = len(out)
            out.append(QVar(len(out), s.name, Kind.MAGNITUDE,
                            available_from=int(getattr(s, "available_from", 0)),
                            resolution=_resolution(s)))
        for s in mags:
            out.append(QVar(len(out), s.name + DOT, Kind.CHANGE, values=CHANGE_LABELS,
                            available_from=int(getattr(s, "available_from", 0)),
                            source=mag_index[s.name]))
        for s in noms:
            values = tuple(str(v) for v in s.values)
            if len(values) < 2:
                raise ValueError(f"nominal {s.name!r} needs at least two values, got {values}")
            out.append(QVar(len(out), s.name, Kind.NOMINAL, values=values,
                            available_from=int(getattr(s, "available_from", 0))))
        return cls(out)

    def __len__(self) -> int:
        return len(self.vars)

    def __iter__(self):
        return iter(self.vars)

    def __getitem__(self, i: int) -> QVar:
        return self.vars[i]

    def index(self, name: str) -> int:
        """Index of a variable by name; a clear error for unknown names."""
        try:
            return self.by_name[name].index
        except KeyError:
            raise KeyError(f"unknown variable {name!r}; known: "
                           f"{', '.join(sorted(self.by_name))}") from None

    def of_kind(self, *kinds: Kind) -> list[QVar]:
        return [v for v in self.vars if v.kind in kinds]

    def to_json(self) -> list[dict]:
        return [{"name": v.name, "kind": v.kind.value, "values": list(v.values), "low": v.low,
                 "high": v.high, "available_from": v.available_from, "source": v.source,
                 "resolution": v.resolution}
                for v in self.vars]

    @classmethod
    def from_json(cls, data: list[dict]) -> VariableTable:
        return cls([QVar(i, d["name"], Kind(d["kind"]), tuple(d.get("values", ())),
                         d.get("low"), d.get("high"), int(d.get("available_from", 0)),
                         int(d.get("source", -1)), d.get("resolution"))
                    for i, d in enumerate(data)])


def _resolution(spec: Any) -> float | None:
    """A world variable's declared resolution, validated (positive and finite) or None."""
    r = getattr(spec, "resolution", None)
    if r is None:
        return None
    r = float(r)
    if not (r > 0 and r < float("inf")):
        raise ValueError(f"variable {spec.name!r} has resolution {r!r}; expected a positive "
                         "finite number or None")
    return r
