"""No module reaches into another module's private names (issue 10: "no module imports a private
name of another module's object").

Every module of the project's packages and scripts is read with :mod:`ast`. A private name is
one with a leading underscore that is not a dunder. A module may use its own private names on
any object (``other._x`` in a method of ``other``'s class, a module function that fills an
object of its own class), but not one it does not define itself:

- ``obj._name`` (read, write or call) where ``obj`` is not ``self``, ``cls`` or ``super()`` and
  the module defines no ``_name`` (a function, class or method, a name it assigns, or an
  attribute it sets on ``self`` or ``cls``);
- ``getattr(obj, "_name")`` and its kin (``setattr``, ``hasattr``, ``delattr``), by the same
  rule;
- ``from module import _name``.

Objects are not typed statically, so a module that defines ``_name`` itself may still use
another module's ``_name`` unseen; the project's modules are small enough that this has not
hidden a case (the controls below show what is found).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("qlap_runtime", "actors", "worlds", "tui", "scripts")
ATTR_FUNCS = ("getattr", "setattr", "hasattr", "delattr")

ALLOWED = {
    # os._exit is os's documented way to end the process from a thread at once (sys.exit
    # there ends only the thread): the experiments' pool worker that lost its parent.
    ("qlap_runtime/experiments/engine.py", "os._exit"),
    # multiprocessing offers no public way to stop its resource tracker, whose process would
    # otherwise outlive the launcher's process group.
    ("qlap_runtime/placements/launcher.py", "resource_tracker._resource_tracker"),
}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _is_self(node: ast.expr) -> bool:
    if isinstance(node, ast.Name):
        return node.id in ("self", "cls")
    return isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
        and node.func.id == "super"


def own_names(tree: ast.AST) -> set[str]:
    """The names a module defines: functions, classes, assigned names, attributes of self/cls."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) \
                and _is_self(node.value):
            names.add(node.attr)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id == "setattr" and len(node.args) > 1 and _is_self(node.args[0]) \
                and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str):
            names.add(node.args[1].value)
    return names


def foreign_private_uses(source: str) -> list[tuple[int, str]]:
    """(line, expression) of every use of another module's private name in ``source``."""
    tree = ast.parse(source)
    own = own_names(tree)
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr) and not _is_self(node.value) \
                and node.attr not in own:
            found.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in ATTR_FUNCS and len(node.args) > 1 \
                and not _is_self(node.args[0]) and isinstance(node.args[1], ast.Constant) \
                and isinstance(node.args[1].value, str) and _private(node.args[1].value) \
                and node.args[1].value not in own:
            found.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if _private(alias.name):
                    found.append((node.lineno, f"from {'.' * node.level}{node.module or ''} "
                                               f"import {alias.name}"))
    return sorted(found)


def private_module_imports(module: str, is_package: bool, source: str) -> list[tuple[int, str]]:
    """(line, import) of every import of a private module (``_format``) from outside the
    package that holds it: ``from .widgets._format import x`` in ``tui.app``, or a library's
    private module (``textual.widgets._data_table``)."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            targets = [[*base, *(node.module or "").split(".")]]
        elif isinstance(node, ast.Import):
            targets = [a.name.split(".") for a in node.names]
        else:
            continue
        for parts in targets:
            parts = [p for p in parts if p]
            for i, part in enumerate(parts):
                if _private(part) and parts[:i] != package:
                    found.append((node.lineno, ".".join(parts)))
                    break
    return found


def test_no_module_imports_a_private_module_from_outside_its_package():
    offenders = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            is_package = rel.name == "__init__"
            module = ".".join(rel.parts[:-1] if is_package else rel.parts)
            offenders += [f"{rel}.py:{line}: {what}"
                          for line, what in private_module_imports(module, is_package,
                                                                   path.read_text())]
    assert offenders == []


def test_the_private_module_check_by_hand():
    """A sibling may import a package's private module; its parent package, another
    package, or any user of a library's private module may not."""
    sibling = "from ._format import a\nimport tui.widgets._format\n"
    assert private_module_imports("tui.widgets.actions", False, sibling) == []
    assert private_module_imports("tui.widgets", True, sibling) == []
    outside = ("from .widgets._format import b\n"
               "from textual.widgets._data_table import C\n"
               "import tui.widgets._format\n")
    assert private_module_imports("tui.app", False, outside) == [
        (1, "tui.widgets._format"), (2, "textual.widgets._data_table"),
        (3, "tui.widgets._format")]


def test_no_module_uses_a_private_name_of_another_module():
    offenders = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for line, expr in foreign_private_uses(path.read_text()):
                if (rel, expr) not in ALLOWED:
                    offenders.append(f"{rel}:{line}: {expr}")
    assert offenders == []


def test_every_allowed_use_still_exists():
    """An allowance whose code is gone is removed from ALLOWED, not left behind."""
    seen = set()
    for rel, _ in ALLOWED:
        seen.update((rel, expr) for _, expr in foreign_private_uses((ROOT / rel).read_text()))
    assert ALLOWED <= seen


def test_the_checker_finds_what_it_forbids_and_nothing_else():
    """The control: each forbidden form is found; the module's own private names, ``self``,
    ``cls``, ``super()`` and dunders are not."""
    source = (
        "from .checkpoint import _read_npz\n"
        "import numpy as np\n"
        "class A:\n"
        "    def __init__(self):\n"
        "        self._mine = 1\n"
        "    def _helper(self, other):\n"
        "        super()._helper(other)\n"
        "        return other._mine + other.__class__.__name__.__len__()\n"
        "    @classmethod\n"
        "    def make(cls):\n"
        "        cls._count = 0\n"
        "        return cls\n"
        "def use(learner, agent, per):\n"
        "    learner._reindex()\n"
        "    agent._seen_applied = 3\n"
        "    x = getattr(per, '_all_seen', None)\n"
        "    y = getattr(per, '_mine')\n"
        "    return np.random._generator, x, y, A()._helper(per)\n"
    )
    assert foreign_private_uses(source) == [
        (1, "from .checkpoint import _read_npz"),
        (14, "learner._reindex"),
        (15, "agent._seen_applied"),
        (16, "getattr(per, '_all_seen', None)"),
        (18, "np.random._generator"),
    ]
