"""Process groups of the processes placement: which actors share a process.

A layout is a tuple of groups, each a tuple of actor names; every actor of the run is in
exactly one group, and each group is one process. What a group's actors share follows from
the layout (``RunContext.groups``, ``RunContext.together``), never from the placement's name:

- world, perception and executor together: one task runs the step chain (the world's task
  hosts the other two, as in the embedded placement);
- contingency and landmarks together: one learner serves both (``actors.learning_pair.run_pair``);
- executor and planner together: ``planreq`` hands over the agent in memory
  (``actors.convert.LocalRequests``) instead of its files.

Layouts by name: ``two`` (the default) — the step chain and the planner in one process, both
learners in a second, so that only ``qstate``, ``batchctx`` and the deltas cross processes and
the learners' work runs on the other core; ``each`` — one process per actor (any actor but the
world can then be restarted alone). A layout can also be spelled out: groups separated by
``,``, the actors of a group by ``+`` (``world+perception+executor+planner,contingency+landmarks``);
a group of several actors holds the world (it is never restarted) or is the learners' pair,
the only actors that snapshot at the same steps, which a restarted group needs.
"""

from __future__ import annotations

ACTORS = ("perception", "contingency", "landmarks", "planner", "executor", "world")
"""Every actor of a run; the world starts last (it waits for the others)."""

LEARNERS = ("contingency", "landmarks")
Layout = tuple[tuple[str, ...], ...]

LAYOUTS: dict[str, Layout] = {
    "two": (("world", "perception", "executor", "planner"), ("contingency", "landmarks")),
    "each": tuple((name,) for name in ACTORS),
}
DEFAULT_GROUPS = "two"


class GroupsError(ValueError):
    """A ``--groups`` value that names no layout (the message names it)."""


def parse_groups(spec: str | Layout) -> Layout:
    """The layout named or spelled out by ``spec`` (see the module docstring), checked: every
    actor of :data:`ACTORS` in exactly one group."""
    if not isinstance(spec, str):
        layout = tuple(tuple(group) for group in spec)
    elif spec in LAYOUTS:
        return LAYOUTS[spec]
    else:
        layout = tuple(tuple(a.strip() for a in g.split("+")) for g in spec.split(","))
    names = [a for group in layout for a in group]
    unknown = sorted(set(names) - set(ACTORS))
    what = None
    if unknown:
        what = f"unknown actor {unknown[0]!r}"
    elif sorted(names) != sorted(ACTORS) or any(not g for g in layout):
        what = "each of the six actors must be in exactly one group"
    elif any(len(g) > 1 and "world" not in g and set(g) != set(LEARNERS) for g in layout):
        # A restartable group resumes all its actors from one snapshot step: only the pair
        # snapshots at the same steps (and planreq in memory cannot be replayed).
        what = "a group of several actors must hold the world or be contingency+landmarks"
    if what is not None:
        raise GroupsError(f"unknown process groups {_show(spec)!r}: {what}; use "
                          f"{' or '.join(LAYOUTS)}, or groups of actors joined by '+' and "
                          f"separated by ',' ({', '.join(ACTORS)})")
    return layout


def _show(spec: str | Layout) -> str:
    return spec if isinstance(spec, str) else ",".join("+".join(g) for g in spec)

