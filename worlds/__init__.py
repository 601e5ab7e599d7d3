"""Worlds for QLAP: physics and task definitions that know nothing of the algorithm.

The contract (:mod:`worlds.base`), the registry (:mod:`worlds.registry`) and the checker
(:mod:`worlds.check`) are re-exported here; the worlds themselves (``core``, ``core2d``, ``pong``,
``gym:ENV_ID``) load their physics engines only when made.
"""

from worlds.base import DOT_BAND as DOT_BAND
from worlds.base import Goal as Goal
from worlds.base import Task as Task
from worlds.base import VariableSpec as VariableSpec
from worlds.base import VarKind as VarKind
from worlds.base import World as World
from worlds.base import direction as direction
from worlds.check import check_world as check_world
from worlds.registry import make as make
from worlds.registry import register as register
from worlds.registry import registered as registered

__all__ = [
    "DOT_BAND",
    "Goal",
    "Task",
    "VarKind",
    "VariableSpec",
    "World",
    "check_world",
    "direction",
    "make",
    "register",
    "registered",
]
