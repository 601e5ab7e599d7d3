"""The core table world of §7.1 (MuJoCo): ``worlds.core.world.CoreWorld`` and its tasks.

MuJoCo picks its OpenGL backend once, when it is first imported. On a Linux machine without a
display, offscreen pictures (``qlap snapshot``) need OSMesa, so ``MUJOCO_GL=osmesa`` is set here
unless the variable is already set or a display is available.
"""

import os
import sys

if (
    sys.platform.startswith("linux")
    and "MUJOCO_GL" not in os.environ
    and not os.environ.get("DISPLAY")
    and not os.environ.get("WAYLAND_DISPLAY")
):
    os.environ["MUJOCO_GL"] = "osmesa"
