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
    # 0: the algorithm, the worlds, and small leaves every layer may use (the root package
    # itself only: a new module under it must be given its layer)
    ("qlap_runtime=", "qlap_runtime.qlap", "qlap_runtime.errors", "qlap_runtime.argtypes",
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


FORBIDDEN: tuple[tuple[str, str], ...] = (
    # Within a layer: the algorithm and the worlds know nothing of each other
    # (docs/architecture.md), and the analysis of runs needs no UI and no experiment.
    ("qlap_runtime.qlap", "worlds"),
    ("worlds", "qlap_runtime"),
    ("qlap_runtime.analysis", "tui"),
    ("qlap_runtime.analysis", "qlap_runtime.experiments"),
)


def within(module: str, name: str) -> bool:
    """``module`` is ``name`` or inside it (``name=``: exactly ``name``)."""
    if name.endswith("="):
        return module == name[:-1]
    return module == name or module.startswith(name + ".")


def layer_of(module: str) -> int:
    best, rank = "", -1
    for i, names in enumerate(LAYERS):
        for name in names:
            if within(module, name) and len(name) > len(best):
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


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes under ``if TYPE_CHECKING:`` (not imported when running)."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return skip


def imports_of(module: str, path: Path, known: dict[str, Path],
               running: bool = False) -> set[str]:
    """Project modules that ``module`` imports (relative imports resolved); ``running``: only
    those imported when the code runs (not under ``if TYPE_CHECKING:``), and not the
    packages that contain ``module`` (``from . import x`` is not a dependency on the
    package's ``__init__``)."""
    found: set[str] = set()
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    tree = ast.parse(path.read_text())
    skip = _type_checking_only(tree) if running else set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
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
        found.update(t for t in targets if t in known and t != module
                     and not (running and module.startswith(t + ".")))
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


def test_no_import_between_modules_a_layer_keeps_apart():
    known = project_modules()
    crossing = [f"{module} imports {target}"
                for module, path in sorted(known.items())
                for target in sorted(imports_of(module, path, known))
                for low, high in FORBIDDEN if within(module, low) and within(target, high)]
    assert crossing == []


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycles():
    """No two modules import each other, directly or round a loop — not even through an
    import inside a function, which only hides a cycle."""
    known = project_modules()
    graph = {m: imports_of(m, p, known, running=True) for m, p in known.items()}
    assert import_cycles(graph) == []


def test_the_cycle_finder_finds_a_loop():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycles(graph) == [["a", "b", "c"]]


def test_the_checker_sees_an_upward_import(tmp_path):
    """The control: a function-level import of a higher layer is found."""
    path = tmp_path / "m.py"
    path.write_text("def f():\n    from ..runtime.launcher import x\n")
    known = {"qlap_runtime.qlap.m": path, "qlap_runtime.runtime.launcher": path}
    assert imports_of("qlap_runtime.qlap.m", path, known) == {"qlap_runtime.runtime.launcher"}
    assert layer_of("qlap_runtime.runtime.launcher") > layer_of("qlap_runtime.qlap.m")
