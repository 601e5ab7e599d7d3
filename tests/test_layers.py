"""Layers import downward only (docs/architecture.md, "Layers").

Every import in the project's packages — at module level or inside a function — is read from
the source with :mod:`ast` and checked against the order below: a module may import its own
layer or a lower one, never a higher one.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LAYERS: tuple[tuple[str, ...], ...] = (
    # 0: the algorithm, the worlds, and small leaves every layer may use
    ("qlap_runtime", "qlap_runtime.qlap", "qlap_runtime.errors", "qlap_runtime.argtypes",
     "worlds"),
    # 1: the bus (messages, keys, recorder) and the metrics of a run
    ("qlap_runtime.bus", "qlap_runtime.metrics"),
    # 2: the actor runtime: lockstep, snapshots, clocks, watchdog, run outcome, telemetry
    ("qlap_runtime.runtime", "qlap_runtime.telemetry"),
    # 3: the actors
    ("actors",),
    # 4: placements: the sync loop, the launcher and supervisor of embedded and processes
    ("qlap_runtime.agent_run", "qlap_runtime.placements"),
    # 5: applications on top of placements: the terminal UI, analysis, experiments
    ("tui", "qlap_runtime.analysis", "qlap_runtime.experiments"),
    # 6: the command line
    ("qlap_runtime.cli",),
)


def layer_of(module: str) -> int:
    best, rank = "", -1
    for i, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > len(best):
                best, rank = name, i
    assert rank >= 0, f"{module} is in no layer: add it to LAYERS"
    return rank


def project_modules() -> dict[str, Path]:
    out = {}
    for folder in ("qlap_runtime", "actors", "worlds", "tui"):
        for path in (ROOT / folder).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def imports_of(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """Project modules that ``module`` imports (relative imports resolved)."""
    found: set[str] = set()
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                prefix = ".".join(package[:len(package) - node.level + 1])
                base = prefix + ("." + base if base else "")
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in known and t != module)
    return found


def test_layers_import_downward_only():
    known = project_modules()
    upward = []
    for module, path in sorted(known.items()):
        for target in sorted(imports_of(module, path, known)):
            if layer_of(target) > layer_of(module):
                upward.append(f"{module} (layer {layer_of(module)}) imports {target} "
                              f"(layer {layer_of(target)})")
    assert upward == []


def test_the_checker_sees_an_upward_import(tmp_path):
    """The control: a function-level import of a higher layer is found."""
    path = tmp_path / "m.py"
    path.write_text("def f():\n    from ..runtime.launcher import x\n")
    known = {"qlap_runtime.qlap.m": path, "qlap_runtime.runtime.launcher": path}
    assert imports_of("qlap_runtime.qlap.m", path, known) == {"qlap_runtime.runtime.launcher"}
    assert layer_of("qlap_runtime.runtime.launcher") > layer_of("qlap_runtime.qlap.m")
