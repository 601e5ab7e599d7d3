"""The world registry: worlds by name, variants as options, any world by import path.

A spec is ``name[:variant[:option]]`` — ``"core"``, ``"core:floating"``,
``"core:secondary:aligned"``, ``"core:transfer:150000"``, ``"pong"``, ``"gym:Pendulum-v1"`` — or
an import path ``"module:Factory"`` (``"package.module:Factory"`` or a top-level
``"mymod:make"``), whose factory is called with the keyword options given to :func:`make`. A
registered name wins: ``core:floating`` is the core world's variant, never an import; a spec whose
first part is not a registered name is imported.

A factory registered by name is called as ``factory(variant, option, **options)`` and returns a
:class:`~worlds.base.World`. Factories may be given as ``"module:attribute"`` strings so that
``import worlds`` stays cheap (MuJoCo, pymunk and Gymnasium load only when a world is made).
A spec that names no world raises :class:`WorldSpecError` (a ``ValueError``) with a one-line
message.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from worlds.base import World

__all__ = ["WorldSpecError", "describe", "make", "register", "registered"]

Factory = Callable[..., World]

_FACTORIES: dict[str, Factory | str] = {}
_VARIANTS: dict[str, tuple[str, ...]] = {}
_BARE: dict[str, bool] = {}
_DESCRIPTIONS: dict[str, str] = {}

IMPORT_FORM = "a plug-in world is given as module:Factory, e.g. mypackage.worlds:make_world"


class WorldSpecError(ValueError):
    """A world spec that names no world: an unknown name, a module or factory that cannot be
    imported, a factory that cannot be called with the options, or one that makes no World."""


def register(
    name: str,
    factory: Factory | str,
    variants: Sequence[str] | Mapping[str, str] = (),
    *,
    bare: bool = True,
    description: str = "",
) -> None:
    """Register a world ``name`` (no ``:``) made by ``factory(variant, option, **options)``.

    ``variants`` lists the specs worth checking besides the bare name (e.g. ``"floating"``,
    ``"secondary:aligned"``), or maps each to a one-line description; :func:`registered` reports
    them and the parametrised world check runs over them. ``bare=False`` says the name alone
    makes no world (``gym`` needs an id). ``description`` is the line ``qlap worlds`` shows.
    """
    if not name or ":" in name or "." in name:
        raise ValueError(f"world names contain no ':' or '.': {name!r}")
    _FACTORIES[name] = factory
    _VARIANTS[name] = tuple(variants)
    _BARE[name] = bare
    _DESCRIPTIONS[name] = description
    if isinstance(variants, Mapping):
        for variant, text in variants.items():
            _DESCRIPTIONS[f"{name}:{variant}"] = text


def registered() -> list[str]:
    """Every registered spec: each name (unless it needs a variant), then each of its listed
    variants as ``name:variant``."""
    out: list[str] = []
    for name in _FACTORIES:
        if _BARE[name]:
            out.append(name)
        out.extend(f"{name}:{variant}" for variant in _VARIANTS[name])
    return out


def describe(spec: str) -> str:
    """The one-line description registered for ``spec`` (a name or ``name:variant``), or ``""``."""
    return _DESCRIPTIONS.get(spec, "")


def _load(target: str) -> Any:
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"an import path is 'module:Factory', got {target!r}")
    module = importlib.import_module(module_name)
    try:
        obj = module
        for part in attribute.split("."):
            obj = getattr(obj, part)
    except AttributeError:
        raise _NoAttribute(f"{module_name!r} has no attribute {attribute!r}") from None
    return obj


class _NoAttribute(ValueError):
    """The module imported but has no such attribute."""


def _unknown(spec: str, why: str) -> WorldSpecError:
    known = ", ".join(sorted(_FACTORIES))
    return WorldSpecError(f"unknown world {spec!r}: {why}; registered worlds: {known} "
                          f"(qlap worlds lists their variants); {IMPORT_FORM}")


def _make_plugin(spec: str, options: dict[str, Any]) -> World:
    """``module:Factory`` (dotted or top-level module) called with ``options``."""
    module_name, _, attribute = spec.partition(":")
    if not module_name or not attribute or ":" in attribute:
        raise _unknown(spec, f"{spec.split(':', 1)[0]!r} is not a registered world")
    try:
        factory = _load(spec)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module_name + ".").startswith(exc.name + "."):
            raise _unknown(spec, f"{module_name!r} is neither a registered world nor an "
                                 f"importable module") from None
        raise WorldSpecError(f"world {spec!r}: importing {module_name!r} failed: {exc}") from exc
    except ImportError as exc:
        raise WorldSpecError(f"world {spec!r}: importing {module_name!r} failed: {exc}") from exc
    except _NoAttribute:
        raise _unknown(spec, f"module {module_name!r} has no factory {attribute!r}") from None
    except Exception as exc:        # the module itself fails: a SyntaxError, its own raise
        raise WorldSpecError(f"world {spec!r}: importing {module_name!r} failed: "
                             f"{type(exc).__name__}: {exc}") from exc
    if not callable(factory):
        raise WorldSpecError(f"world {spec!r}: {attribute!r} is a {type(factory).__name__}, "
                             f"not a factory; {IMPORT_FORM}")
    try:
        inspect.signature(factory).bind(**options)
    except TypeError as exc:
        given = f"the options {', '.join(sorted(options))}" if options else "no arguments"
        raise WorldSpecError(f"world {spec!r} is not a world factory (it cannot be called with "
                             f"{given}: {exc}); {IMPORT_FORM}") from None
    except ValueError:              # no signature (a builtin): let the call decide
        pass
    try:
        world = factory(**options)
    except Exception as exc:
        raise WorldSpecError(f"world {spec!r}: its factory {attribute!r} raised "
                             f"{type(exc).__name__}: {exc}") from exc
    if not isinstance(world, World):
        raise WorldSpecError(f"world {spec!r} made a {type(world).__name__}, not a worlds.World")
    return world


def make(spec: str, **options: Any) -> World:
    """Make the world named by ``spec`` (see the module docstring) with keyword ``options``:
    a registered name first, else an import path ``module:Factory``."""
    name, _, rest = spec.partition(":")
    factory = _FACTORIES.get(name)
    if factory is None:
        if not rest:
            raise _unknown(spec, "not a registered world")
        return _make_plugin(spec, options)
    variant, _, option = rest.partition(":")
    if isinstance(factory, str):
        factory = _load(factory)
        _FACTORIES[name] = factory
    return factory(variant or None, option or None, **options)


register(
    "core",
    "worlds.core.world:make_core",
    variants={
        "floating": "core plus two balls drifting out of reach (§7.4.1)",
        "random1": "floating plus 3 uniform random variables (§7.6.1)",
        "random2": "floating plus 6 uniform random variables (§7.6.1)",
        "relevant1": "core plus extra hand/block edge variables (§7.6.1)",
        "relevant2": "core plus more hand/block edge variables (§7.6.1)",
        "secondary:aligned": "a second block out of reach on a larger table, aligned (§7.8.1)",
        "secondary:unaligned": "a second block out of reach, unaligned (§7.8.1)",
        "contingent:rising": "floating, ball 1 rising with the hand (§7.9.1)",
        "contingent:jump": "floating, ball 1 jumping with the hand (§7.9.1)",
        "transfer:100": "bang and z_F withheld until step 100 (transfer[:STEP], §7.5)",
    },
    description="the core table world of §7.1 in MuJoCo: a hand on three slide motors, a block",
)
register(
    "core2d",
    "worlds.core2d.world:make_core2d",
    description="the core world seen from above in pymunk, the hand moving in x, y (§7.7)",
)
register("pong", "worlds.pong.world:make_pong",
         description="Pong (§7.10): two paddles moving together in y, one ball to volley")
register(
    "gym",
    "worlds.gym_wrapper:make_gym",
    variants={
        "Pendulum-v1": "Gymnasium's Pendulum-v1 (gym:ENV_ID: any Box-observation environment)",
        "MountainCarContinuous-v0": "Gymnasium's MountainCarContinuous-v0",
    },
    bare=False,
    description="a Gymnasium environment with a Box observation space, gym:ENV_ID",
)
