"""The world's bodies for Foxglove's 3D panel: ``foxglove.SceneUpdate`` messages (docs/bus.md).

Schema and encoding are Foxglove's own, from the ``foxglove-schemas-protobuf`` package
(Foxglove's precompiled Protobuf schemas): the MCAP schema is named ``foxglove.SceneUpdate``, has
the ``protobuf`` encoding and holds the FileDescriptorSet of ``foxglove/SceneUpdate.proto`` and
of every file it imports (:func:`file_descriptor_set`); messages are Protobuf-encoded.

A world that can be drawn has a ``scene(values)`` method (``worlds/core``, ``worlds/core2d``)
returning its bodies as boxes and spheres in a right-handed, z-up frame from an observation (a
``sense`` message's values). :class:`SceneMaker` builds the run's world once and turns each
observation into one ``SceneUpdate``: every body an entity of frame :data:`FRAME`, whose id is
the body's (``table``, ``hand``, ``block``, ...), all of them in every message, so that a viewer
that seeks anywhere in a recording sees the whole scene.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorSet

log = logging.getLogger("qlap.bus")

SCENE_SCHEMA = "foxglove.SceneUpdate"
"""The MCAP schema name Foxglove recognises (its Protobuf message's full name)."""

FRAME = "world"
"""The frame id of every entity (the only frame: no transforms are needed)."""


def file_descriptor_set(message_type: Any = SceneUpdate) -> bytes:
    """The serialized ``FileDescriptorSet`` of a Protobuf message type's file and every file it
    imports, imports first: the data of an MCAP schema with the ``protobuf`` encoding."""
    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        fd.CopyToProto(fds.file.add())

    add(message_type.DESCRIPTOR.file)
    return fds.SerializeToString()


def scene_update(bodies: list[Mapping[str, Any]], stamp_ns: int,
                 metadata: Mapping[str, str] | None = None) -> SceneUpdate:
    """One ``SceneUpdate`` with an entity per body (``{"id", "shape": "box" | "sphere",
    "centre", "size", "rgba"}``, as ``World.scene`` gives them) stamped ``stamp_ns``; each
    entity carries ``metadata`` (e.g. the step) as key/value pairs."""
    update = SceneUpdate()
    for body in bodies:
        entity = update.entities.add()
        entity.timestamp.FromNanoseconds(stamp_ns)
        entity.frame_id = FRAME
        entity.id = str(body["id"])
        for k, v in (metadata or {}).items():
            kv = entity.metadata.add()
            kv.key, kv.value = k, v
        shape = body.get("shape", "box")
        if shape == "box":
            prim = entity.cubes.add()
        elif shape == "sphere":
            prim = entity.spheres.add()
        else:
            raise ValueError(f"body {body['id']!r}: unknown shape {shape!r}")
        p = prim.pose.position
        p.x, p.y, p.z = (float(c) + 0.0 for c in body["centre"])    # + 0.0: no −0.0
        prim.pose.orientation.w = 1.0            # Protobuf's default quaternion is all zeros
        s = prim.size
        s.x, s.y, s.z = (float(c) for c in body["size"])
        c = prim.color
        c.r, c.g, c.b, c.a = (float(x) for x in body["rgba"])
    return update


class SceneMaker:
    """The run's world (``worlds.make(spec)``, built once, never stepped) drawing observations.

    Raises ``ValueError`` when the world cannot be built here or has no ``scene`` method."""

    def __init__(self, spec: str) -> None:
        import worlds

        try:
            world = worlds.make(spec)
        except Exception as e:  # an unknown or unimportable plug-in, a missing extra
            raise ValueError(f"world {spec!r} cannot be built here: {type(e).__name__}: {e}")\
                from None
        if not callable(getattr(world, "scene", None)):
            world.close()
            raise ValueError(f"world {spec!r} has no scene() to draw")
        self.spec = spec
        self.world: Any = world          # a World with a scene() method

    def __call__(self, values: Mapping[str, float], stamp_ns: int, step: int) -> bytes | None:
        """The encoded ``SceneUpdate`` of an observation; None when the observation lacks a
        variable the drawing needs (a withheld variable, another world's message)."""
        try:
            bodies = self.world.scene(dict(values))
        except KeyError:
            return None
        return scene_update(bodies, stamp_ns, {"step": str(step)}).SerializeToString()

    def close(self) -> None:
        self.world.close()
