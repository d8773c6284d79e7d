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
    "analysis/accuracy.py": ["accuracy"],
    "analysis/identifiability.py": ["identifiability"],
    "analysis/uncertainty.py": ["uncertainty"],
    "methods/__init__.py": ["identify"],
    "estimation.py": ["efficient"],
    "fit_test.py": ["fit_check"],
    "simulation.py": ["simulate"],
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
    """iwr.kinds is the bottom layer: its kinds are imported by name on first use. It imports
    the generic registry (iwr._registry, shared with iwr.effects) and nothing else of iwr; the
    registry imports nothing of iwr at all."""
    for path, allowed in (("kinds/__init__.py", {(2, "_registry")}), ("_registry.py", set())):
        tree = ast.parse((REPO / "iwr" / path).read_text())
        for node in tree.body:
            if isinstance(node, ast.ImportFrom):
                assert ((node.level == 0 and node.module in ("__future__", "typing",
                                                             "collections.abc"))
                        or (node.level, node.module) in allowed), ast.dump(node)
            elif isinstance(node, ast.Import):
                assert all(not a.name.startswith("iwr") for a in node.names)


def test_no_import_cycle(layers):
    """No strongly connected component in iwr's import graph (every import counts: module level,
    in a function, under TYPE_CHECKING, and what a package's initialiser imports)."""
    edges, _ = layers.graph(REPO)
    assert layers.cycles(edges) == []


def test_every_module_has_a_layer(layers):
    assert layers.unlisted(REPO) == []


def test_no_upward_import(layers):
    """No module imports one of a higher layer of tools/layers.py's LAYERS; a lower layer that
    must call up does so through a registered hook (iwr._hooks, the kinds' registry)."""
    assert [f"{i.source} -> {i.target} (line {i.line}{', via ' + i.via if i.via else ''})"
            for i in layers.upward(REPO)] == []


def test_every_hook_names_a_higher_module_and_resolves(layers):
    """Each registered hook names an attribute of a module of the same or a higher layer, and
    importing it by that name gives it (a renamed module or function breaks this, not a user)."""
    import importlib

    from iwr._hooks import HOOKS, hook

    assert layers.broken_hooks(REPO) == []
    found = {spec for _, _, spec in layers.hooks(REPO)}
    assert set(HOOKS.values()) <= found and len(found) > len(HOOKS)  # and the kinds'
    for name in HOOKS:
        assert hook(name) is not None
    for spec in found:
        module, _, attribute = spec.partition(":")
        assert hasattr(importlib.import_module(module), attribute), spec
    with pytest.raises(KeyError, match="not registered"):
        hook("no such hook")


def test_no_submodule_is_shadowed(layers):
    """No package binds a submodule's name to something else (``iwr.simulate`` is the function,
    the module is ``iwr.simulation``)."""
    assert layers.shadowed(REPO) == []


def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_tool_sees_cycles_upward_imports_and_unlisted_modules(layers, tmp_path):
    """The checks above are not blind: on a made-up package the tool finds a cycle, an upward
    import at module level, one inside a function, one through a package's initialiser, a
    module missing from the table, and a hook that names nothing."""
    assert layers.cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    root = _tree(tmp_path, {
        "iwr/__init__.py": "",
        "iwr/low.py": "from . import high\n",
        "iwr/mid.py": "def f():\n    from .high import x\n    return x\n",
        "iwr/high.py": "x = 1\n",
        "iwr/pkg/__init__.py": "from .api import y\n",
        "iwr/pkg/setup.py": "",
        "iwr/pkg/api.py": "y = 2\n",
        "iwr/data.py": "from .pkg.setup import *\n",
        "iwr/kinds/__init__.py": "register('x', 'iwr.nowhere:Kind')\n",
    })
    table = [("low", ["iwr.low", "iwr.mid", "iwr.data", "iwr.pkg.setup", "iwr.kinds"]),
             ("high", ["iwr.high", "iwr.pkg", "iwr.pkg.api"]), ("top", ["iwr"])]
    up = {(i.source, i.target, i.in_function, i.via) for i in layers.upward(root, table)}
    assert up == {("iwr.low", "iwr.high", False, ""), ("iwr.mid", "iwr.high", True, ""),
                  ("iwr.data", "iwr.pkg.api", False, "iwr.pkg")}
    assert layers.unlisted(root, table[1:]) == ["iwr.data", "iwr.kinds", "iwr.low", "iwr.mid",
                                                "iwr.pkg.setup"]
    assert layers.unlisted(root, table) == []
    assert layers.shadowed(root) == []
    (root / "iwr" / "pkg" / "__init__.py").write_text("from .api import y\n\n\ndef setup():\n"
                                                      "    pass\n")
    assert layers.shadowed(root) == ["iwr.pkg.setup"]
    assert layers.broken_hooks(root) == ["iwr/kinds/__init__.py:1: iwr.nowhere:Kind: no module "
                                         "iwr.nowhere"]
    (root / "iwr" / "high.py").write_text("from . import mid\n")
    assert layers.cycles(layers.graph(root)[0]) == [["iwr.high", "iwr.mid"]]
