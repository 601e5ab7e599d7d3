"""The core table world of §7.1 (MuJoCo): ``worlds.core.world.CoreWorld`` and its tasks."""
