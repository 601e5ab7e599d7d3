"""Tiny real runs for the analysis tests: core2d, synchronous loop, a checkpoint every 1,000."""

from pathlib import Path

import pytest


def tiny_run(out: Path, seed: int, steps: int = 3000) -> Path:
    import worlds
    from qlap_runtime.agent_run import run_agent
    from qlap_runtime.qlap import Params

    world = worlds.make("core2d")
    try:
        run_agent(world, steps, seed, out, params=Params(babble_steps=1000),
                  checkpoint_every=1000)
    finally:
        world.close()
    return out


@pytest.fixture(scope="session")
def runs(tmp_path_factory) -> list[Path]:
    """Two 3,000-step runs (seeds 1, 2): step-0001000 … step-0003000 and a duplicate final."""
    root = tmp_path_factory.mktemp("runs")
    return [tiny_run(root / f"s{seed}", seed) for seed in (1, 2)]
