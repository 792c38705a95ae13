"""The package layout keeps its rules (DEVELOPING.md): imports follow the data flow, private
names stay in their module, modules stay small, and each shared mechanism exists once.

These are static checks over the source (``ast``), so a change that breaks a rule fails
here with the file and line, before a reviewer has to find it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "casflex"

# The data flow, left to right: a module may import from its own top-level package and
# from packages of a lower rank, never of a higher one. Shared mechanisms and errors are at
# the bottom; so is codegen's generic C toolchain (compiler, bundles, JIT library cache),
# which knows nothing of robots and serves simulation as well as the estimator's code.
# plotting is a leaf every layer may hand figures to: it imports casflex's domain modules
# only inside functions or for type checking (checked below). Keys are top-level modules
# or dotted sub-modules (the longest match wins).
RANK = {
    "errors": 0, "_cache": 0, "_validate": 0, "_problemfile": 0, "_json": 0,
    "_parallel": 0, "plotting": 0, "plotting_report": 0,
    "codegen.build": 0.5, "codegen.bundle": 0.5, "codegen.templates": 0.5,
    "codegen.jit": 0.5,
    "robot": 1,
    "tmm": 2,
    "modal": 3,
    "identification": 3.5,
    "model": 4,
    "sensors": 5.0, "sensor_tables": 5.0, "moves": 5.1, "shaping": 5.2, "control": 5.3,
    "simulate": 6,
    "planning": 6.5,
    "estimation": 7,
    "codegen": 8,
    "design": 9,
    "commands": 10, "cli": 10,
}

MAX_LINES = 1000


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield path, ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _ranked(parts):
    """The RANK key of a module given as its parts below ``casflex`` (longest match)."""
    for k in range(len(parts), 0, -1):
        key = ".".join(parts[:k])
        if key in RANK:
            return key
    return parts[0] if parts else None


def _top(module_name):
    """``"shaping"`` for ``casflex.shaping.si``; ``None`` for ``casflex`` itself."""
    parts = module_name.split(".")
    return _ranked(parts[1:]) if len(parts) > 1 and parts[0] == "casflex" else None


def _own_top(path):
    parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return _ranked(parts) if parts else None


def _imports(tree):
    """``(line, imported casflex module, names, at module level)`` for every import."""
    toplevel = set()

    def visit(statements):  # module level, through if/try blocks, not into def/class
        for node in statements:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue  # type-only imports do not run
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                toplevel.add(id(node))
            for field in ("body", "orelse", "finalbody", "handlers"):
                if isinstance(node, (ast.If, ast.Try, ast.ExceptHandler, ast.With)):
                    visit(getattr(node, field, []))

    visit(tree.body)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.lineno, node.module, [a.name for a in node.names], id(node) in toplevel
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, [], id(node) in toplevel


def test_every_top_level_module_has_a_rank():
    tops = {_own_top(p) for p, _ in _modules()} - {None}
    assert tops <= set(RANK), f"give these a rank in RANK: {sorted(tops - set(RANK))}"


def test_imports_follow_the_data_flow():
    offenders = []
    for path, tree in _modules():
        own = _own_top(path)
        if own not in RANK or own == "plotting":  # casflex/__init__.py; unranked modules
            continue  # fail the test above; plotting has its own rule
        for line, module, names, _ in _imports(tree):
            targets = [module] if module != "casflex" else [f"casflex.{n}" for n in names]
            for target in targets:
                top = _top(target)
                if top is None or top.split(".")[0] == own.split(".")[0] or top not in RANK:
                    continue
                if RANK[top] > RANK[own]:
                    offenders.append(f"{path.relative_to(ROOT)}:{line}: {own} imports "
                                     f"{target} (further down the data flow)")
    assert not offenders, "\n".join(offenders)


def test_plotting_imports_domain_modules_only_where_it_draws():
    path = PACKAGE / "plotting.py"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    offenders = [f"plotting.py:{line}: {module}" for line, module, _, toplevel in _imports(tree)
                 if toplevel and module.startswith("casflex")
                 and RANK.get(_top(module), 0) > 0]
    assert not offenders, "\n".join(offenders)


def test_no_private_name_is_used_outside_its_module():
    """``from casflex.x import _name`` and ``module._name`` reach into another module."""
    offenders = []
    trees = list(_modules())
    for folder in ("tests", "benchmarks", "tools", "notebooks"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            trees.append((path, ast.parse(path.read_text(encoding="utf-8"))))
    for path, tree in trees:
        aliases = {}  # local name -> casflex module it stands for
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(
                    "casflex"):
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: "
                                         f"from {node.module} import {a.name}")
                    aliases[a.asname or a.name] = f"{node.module}.{a.name}"
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("casflex"):
                        aliases[a.asname or a.name.split(".")[0]] = a.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                base = node.value
                while isinstance(base, ast.Attribute):
                    base = base.value
                if isinstance(base, ast.Name) and base.id in aliases:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: "
                                     f"{ast.unparse(node)}")
    assert not offenders, "\n".join(offenders)


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_module_is_at_most_1000_lines(path):
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= MAX_LINES, f"{path.name}: {lines} lines; split it by topic"


def test_one_runge_kutta_step():
    """The classical RK4 combination is written once (casflex.simulate.integrators)."""
    pattern = re.compile(r"k1\s*\+\s*2\.?0?\s*\*\s*k2\s*\+\s*2\.?0?\s*\*\s*k3\s*\+\s*k4")
    places = [f"{p.relative_to(ROOT)}:{text[:m.start()].count(chr(10)) + 1}"
              for p in PACKAGE.rglob("*.py")
              for text in [p.read_text(encoding="utf-8")]
              for m in pattern.finditer(text)]
    assert len(places) <= 2, "RK4 written more than twice: " + ", ".join(places)
    assert any("integrators.py" in p for p in places)


def test_package_marks_itself_typed_and_licensed():
    assert (PACKAGE / "py.typed").is_file()
    assert (ROOT / "LICENSE").is_file()
    assert 'casflex = ["py.typed"]' in (ROOT / "pyproject.toml").read_text()
