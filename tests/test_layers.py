"""The package's shape (tools/layers.py reads the import graph with ast): the public functions
reach every kind of data through iwr.kinds, never by testing a type; the kinds' registry sits at
the bottom; import cycles do not grow."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def layers():
    spec = importlib.util.spec_from_file_location("layers", REPO / "tools" / "layers.py")
    module = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(module)
    return module


# The public functions that serve every kind of data (issue 21), by module.
PUBLIC = {
    "accuracy.py": ["accuracy"],
    "identifiability.py": ["identifiability"],
    "uncertainty.py": ["uncertainty"],
    "methods/__init__.py": ["identify"],
    "estimation.py": ["efficient", "fit_check"],
    "simulate.py": ["simulate"],
    "planning.py": ["plan_poses", "measure", "_as_candidates"],
}

KIND_TYPES = {"Measurements", "TrackerMeasurements", "TrackerProblem", "Problem"}


def _kind_tests(fn: ast.FunctionDef) -> list[str]:
    """What in ``fn`` chooses a path by the kind of the data: isinstance with a data or problem
    type, ``type(x).__name__``, or a test of ``robot.tracker``."""
    found = []
    for node in ast.walk(fn):
        if (isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance"
                and len(node.args) == 2):
            names = {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)}
            if names & KIND_TYPES:
                found.append(f"line {node.lineno}: isinstance(..., {sorted(names & KIND_TYPES)})")
        if isinstance(node, ast.Compare):  # (a type's name in a message is no branch)
            for side in [node.left, *node.comparators]:
                if isinstance(side, ast.Attribute) and side.attr == "tracker":
                    found.append(f"line {node.lineno}: a test of .tracker")
                if isinstance(side, ast.Attribute) and side.attr == "__name__":
                    found.append(f"line {node.lineno}: a type's __name__")
    return found


@pytest.mark.parametrize("module", sorted(PUBLIC))
def test_public_functions_do_not_branch_on_the_kind(module):
    tree = ast.parse((REPO / "iwr" / module).read_text())
    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    for name in PUBLIC[module]:
        assert name in functions, f"{module}: no function {name}"
        assert _kind_tests(functions[name]) == [], f"{module}: {name}"


def test_the_rule_sees_a_branch_on_the_kind():
    """The check above is not blind: it finds each form of a branch on the kind."""
    src = ("def f(robot, m):\n"
           "    if isinstance(m, TrackerMeasurements): pass\n"
           "    if type(m).__name__ == 'X': pass\n"
           "    if robot.tracker is not None: pass\n")
    fn = ast.parse(src).body[0]
    assert isinstance(fn, ast.FunctionDef) and len(_kind_tests(fn)) == 3


def test_no_type_is_chosen_by_its_name(layers):
    assert layers.type_name_tests(REPO) == []


def test_the_registry_imports_nothing_of_iwr_at_module_level():
    """iwr.kinds is the bottom layer: its kinds are imported by name on first use."""
    tree = ast.parse((REPO / "iwr" / "kinds" / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            assert node.level == 0 and node.module in ("__future__", "typing"), ast.dump(node)
        elif isinstance(node, ast.Import):
            assert all(not a.name.startswith("iwr") for a in node.names)


def test_import_cycles_do_not_grow(layers):
    """A ratchet: the largest import cycle (strongly connected component) of iwr. Lower the
    number when a cycle is broken; never raise it."""
    edges, _ = layers.graph(REPO)
    comps = layers.cycles(edges)
    assert max((len(c) for c in comps), default=0) <= 6, comps
    # The tool sees a cycle where there is one.
    assert layers.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
