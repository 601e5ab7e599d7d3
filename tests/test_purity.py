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


def test_no_pickle_anywhere_in_the_project():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    offenders = []
    for folder in ("qlap_runtime", "actors", "worlds", "tui", "scripts"):
        for path in (root / folder).rglob("*.py"):
            text = path.read_text()
            if "import pickle" in text or "allow_pickle=True" in text or "cloudpickle" in text:
                offenders.append(str(path.relative_to(root)))
    assert offenders == []
