"""``qlap snapshot``: a PNG picture of a MuJoCo world, with MuJoCo's offscreen renderer.

``main_snapshot(["--world", "core:secondary:aligned", "--out", "scene.png", "--seed", "3"])``
resets the world with the seed, optionally runs ``--steps`` random-motor steps, and renders the
``overview`` camera (behind and above the robot). Offscreen rendering needs a GL backend: this
package sets ``MUJOCO_GL=osmesa`` when no display is available and the variable is not set (on
Debian: ``apt-get install libosmesa6``). The renderer is closed explicitly (MuJoCo errors at exit
otherwise). The PNG is written with the standard library (zlib), no imaging package needed.
"""

from __future__ import annotations

import argparse
import os
import struct
import sys
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

import worlds.core  # noqa: F401 - chooses MuJoCo's GL backend before MuJoCo is imported

__all__ = ["main_snapshot", "render_png", "write_png"]


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 array as an 8-bit RGB PNG."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    height, width, channels = rgb.shape
    if channels != 3:
        raise ValueError(f"expected an RGB image, got shape {rgb.shape}")
    raw = b"".join(b"\x00" + rgb[row].tobytes() for row in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    path = Path(path)                  # whole or not at all: a temporary file, then a rename
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_bytes(png)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def render_png(
    spec: str,
    out: str | Path,
    seed: int = 0,
    steps: int = 0,
    width: int = 800,
    height: int = 600,
    camera: str = "overview",
) -> Path:
    """Render world ``spec`` after reset(seed) and ``steps`` random-motor steps to ``out``."""
    import mujoco

    from worlds.check import random_motor
    from worlds.registry import make

    world = make(spec)
    try:
        model = getattr(world, "model", None)
        data = getattr(world, "data", None)
        if model is None or data is None:
            raise ValueError(f"{spec}: only MuJoCo worlds (core and its variants) can be rendered")
        world.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(steps):
            world.step(random_motor(world, rng))
        world.sync_visuals()  # type: ignore[attr-defined]
        mujoco.mj_forward(model, data)
        renderer = mujoco.Renderer(model, height=height, width=width)
        try:
            renderer.update_scene(data, camera=camera)
            pixels = renderer.render()
        finally:
            renderer.close()
    finally:
        world.close()
    path = Path(out)
    write_png(path, pixels)
    return path


def main_snapshot(argv: Sequence[str] | None = None) -> int:
    """``--world SPEC --out FILE.png [--seed N] [--steps N] [--camera NAME]``; returns 0 or 2."""
    parser = argparse.ArgumentParser(prog="qlap snapshot", description=__doc__.split("\n")[0])
    parser.add_argument("--world", default="core", help="world spec, e.g. core:secondary:aligned")
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=0, help="random-motor steps before rendering")
    parser.add_argument("--camera", default="overview", help="overview (default) or top")
    parser.add_argument("--width", type=int, default=800)
    parser.add_argument("--height", type=int, default=600)
    args = parser.parse_args(argv)
    try:
        path = render_png(
            args.world, args.out, args.seed, args.steps, args.width, args.height, args.camera
        )
    except (ValueError, RuntimeError, mujoco_error()) as error:
        print(f"qlap snapshot: {error}", file=sys.stderr)
        return 2
    print(path)
    return 0


def mujoco_error() -> type[Exception]:
    """MuJoCo's FatalError class (GL context failures), or a never-raised stand-in."""
    try:
        import mujoco

        return mujoco.FatalError  # type: ignore[no-any-return]
    except (ImportError, AttributeError):  # pragma: no cover
        return RuntimeError


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main_snapshot())
