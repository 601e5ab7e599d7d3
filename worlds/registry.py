"""The world registry: worlds by name, variants as options, any world by import path.

A spec is ``name[:variant[:option]]`` — ``"core"``, ``"core:floating"``,
``"core:secondary:aligned"``, ``"core:transfer:150000"``, ``"pong"``, ``"gym:Pendulum-v1"`` — or
an import path ``"package.module:Factory"`` (a spec with a ``.`` before its first ``:``), whose
factory is called with the keyword options given to :func:`make`.

A factory registered by name is called as ``factory(variant, option, **options)`` and returns a
:class:`~worlds.base.World`. Factories may be given as ``"module:attribute"`` strings so that
``import worlds`` stays cheap (MuJoCo, pymunk and Gymnasium load only when a world is made).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any

from worlds.base import World

__all__ = ["make", "register", "registered"]

Factory = Callable[..., World]

_FACTORIES: dict[str, Factory | str] = {}
_VARIANTS: dict[str, tuple[str, ...]] = {}
_BARE: dict[str, bool] = {}


def register(
    name: str, factory: Factory | str, variants: Sequence[str] = (), *, bare: bool = True
) -> None:
    """Register a world ``name`` (no ``:``) made by ``factory(variant, option, **options)``.

    ``variants`` lists the specs worth checking besides the bare name (e.g. ``"floating"``,
    ``"secondary:aligned"``); :func:`registered` reports them and the parametrised world check
    runs over them. ``bare=False`` says the name alone makes no world (``gym`` needs an id).
    """
    if not name or ":" in name or "." in name:
        raise ValueError(f"world names contain no ':' or '.': {name!r}")
    _FACTORIES[name] = factory
    _VARIANTS[name] = tuple(variants)
    _BARE[name] = bare


def registered() -> list[str]:
    """Every registered spec: each name (unless it needs a variant), then each of its listed
    variants as ``name:variant``."""
    out: list[str] = []
    for name in _FACTORIES:
        if _BARE[name]:
            out.append(name)
        out.extend(f"{name}:{variant}" for variant in _VARIANTS[name])
    return out


def _load(target: str) -> Any:
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"an import path is 'package.module:Factory', got {target!r}")
    module = importlib.import_module(module_name)
    try:
        obj = module
        for part in attribute.split("."):
            obj = getattr(obj, part)
    except AttributeError:
        raise ValueError(f"{module_name!r} has no attribute {attribute!r}") from None
    return obj


def make(spec: str, **options: Any) -> World:
    """Make the world named by ``spec`` (see the module docstring) with keyword ``options``."""
    head = spec.split(":", 1)[0]
    if "." in head:
        world = _load(spec)(**options)
        if not isinstance(world, World):
            raise TypeError(f"{spec!r} made {type(world).__name__}, not a worlds.World")
        return world
    name, _, rest = spec.partition(":")
    variant, _, option = rest.partition(":")
    factory = _FACTORIES.get(name)
    if factory is None:
        known = ", ".join(sorted(_FACTORIES))
        raise ValueError(f"unknown world {name!r} in spec {spec!r}; registered worlds: {known}")
    if isinstance(factory, str):
        factory = _load(factory)
        _FACTORIES[name] = factory
    return factory(variant or None, option or None, **options)


register(
    "core",
    "worlds.core.world:make_core",
    variants=(
        "floating",
        "random1",
        "random2",
        "relevant1",
        "relevant2",
        "secondary:aligned",
        "secondary:unaligned",
        "contingent:rising",
        "contingent:jump",
        "transfer:100",
    ),
)
register("core2d", "worlds.core2d.world:make_core2d")
register("pong", "worlds.pong.world:make_pong")
register(
    "gym",
    "worlds.gym_wrapper:make_gym",
    variants=("Pendulum-v1", "MountainCarContinuous-v0"),
    bare=False,
)
