"""Tiny real runs for the analysis tests: core2d, synchronous loop, a checkpoint every 1,000."""

from pathlib import Path

import pytest


def tiny_run(out: Path, seed: int, steps: int = 3000, babble_steps: int = 1000,
             checkpoint_every: int = 1000) -> Path:
    import worlds
    from qlap_runtime.agent_run import run_agent
    from qlap_runtime.qlap import Params

    world = worlds.make("core2d")
    try:
        run_agent(world, steps, seed, out, params=Params(babble_steps=babble_steps),
                  checkpoint_every=checkpoint_every)
    finally:
        world.close()
    return out


@pytest.fixture(scope="session")
def runs(tmp_path_factory) -> list[Path]:
    """Two 3,000-step runs (seeds 1, 2): step-0001000 … step-0003000 and a duplicate final."""
    root = tmp_path_factory.mktemp("runs")
    return [tiny_run(root / f"s{seed}", seed) for seed in (1, 2)]


@pytest.fixture(scope="session")
def grown(tmp_path_factory) -> Path:
    """A 10,000-step run (seed 1, babbling for 2,000) that has learned DBNs, plans and
    landmarks by its later checkpoints (about a second)."""
    root = tmp_path_factory.mktemp("grown")
    return tiny_run(root / "g1", 1, steps=10_000, babble_steps=2000)
