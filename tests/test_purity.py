"""The algorithm is a library with no I/O (docs/architecture.md §1 rule 1)."""

import subprocess
import sys

FORBIDDEN = ("zenoh", "trio", "textual", "mujoco", "pymunk")


def test_algorithm_imports_no_io_or_physics_modules():
    code = (
        "import sys, qlap_runtime.qlap, qlap_runtime.qlap.checkpoint, qlap_runtime.qlap.mdp\n"
        "import pkgutil, importlib\n"
        "for m in pkgutil.iter_modules(qlap_runtime.qlap.__path__):\n"
        "    importlib.import_module('qlap_runtime.qlap.' + m.name)\n"
        f"bad = [m for m in {FORBIDDEN!r} if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "", f"the algorithm imported: {out}"


def test_public_names_are_pinned():
    import qlap_runtime.qlap as q

    assert sorted(n for n in dir(q) if not n.startswith("_") and n[0].isupper()) == [
        "Ablations", "Delta", "Event", "InvalidObservation", "Kind", "Landmark",
        "ModelLearner", "Params", "Percept", "QuantitySpace", "VariableTable"]


FOLDERS = ("qlap_runtime", "actors", "worlds", "tui", "scripts")


def project_sources():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            yield str(path.relative_to(root)), path.read_text()


def test_no_pickle_anywhere_in_the_project():
    """No module serialises objects with pickle or its kin; what crosses a process boundary
    is JSON text (checked here for the pools and spawned processes that take arguments)."""
    import re

    pattern = re.compile(r"^\s*(import|from)\s+(c?pickle|cloudpickle|dill|marshal|shelve)\b"
                         r"|allow_pickle\s*=\s*True", re.M)
    assert [name for name, text in project_sources() if pattern.search(text)] == []


def test_every_random_choice_draws_from_a_seeded_generator():
    """No ``random`` module, no numpy global-state functions, no unseeded default_rng()."""
    import re

    pattern = re.compile(
        r"^\s*(import random\b|from random import)"
        r"|np\.random\.(seed|rand|randn|randint|random|choice|shuffle|permutation|uniform|"
        r"normal|integers|RandomState)\("
        r"|default_rng\(\s*\)", re.M)
    found = [f"{name}: {m.group(0).strip()}" for name, text in project_sources()
             for m in pattern.finditer(text)]
    assert found == []
