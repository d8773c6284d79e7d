"""The import graph of the iwr package, read with ``ast`` (nothing is imported): its cycles
(strongly connected components), the imports made inside functions, and where a module tests
the type of its data by name.

    python tools/layers.py [REPO]          # a table; exit 1 if a type is tested by its name

Every import counts, at module level or inside a function (a function-level import only defers
the cycle it closes). Not seen: the kinds that iwr.kinds imports by name on first use
(``register("pose", "iwr.kinds.pose:PoseKind")``), which sit above the public functions.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path


def modules(root: Path) -> dict[str, Path]:
    """Module name -> file, for every ``.py`` file of ``root/iwr``."""
    out = {}
    # A compiled module (its stub, iwr/_core.pyi) is a leaf: it imports nothing of iwr.
    for p in sorted((root / "iwr").rglob("*.py")) + sorted((root / "iwr").rglob("*.pyi")):
        if p.suffix == ".pyi" and p.with_suffix(".py").exists():
            continue
        parts = list(p.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = p
    return out


def _targets(mods: dict[str, Path], module: str, node: ast.AST) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name in mods]
    assert isinstance(node, ast.ImportFrom)
    if node.level:
        base = module.split(".")
        if mods[module].name != "__init__.py":
            base = base[:-1]
        base = base[:len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    out = []
    for alias in node.names:
        sub = f"{target}.{alias.name}"
        out.append(sub if sub in mods else target)
    return [t for t in out if t in mods]


def graph(root: Path) -> tuple[dict[str, set[str]], dict[str, int]]:
    """``(edges, inner)``: module -> the iwr modules it imports; module -> how many of its
    imports sit inside functions."""
    mods = modules(root)
    edges: dict[str, set[str]] = defaultdict(set)
    inner: dict[str, int] = defaultdict(int)
    for name, path in mods.items():
        edges.setdefault(name, set())
        if path.suffix == ".pyi":
            continue
        tree = ast.parse(path.read_text(), str(path))
        in_function = set()
        for f in ast.walk(tree):
            if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
                in_function.update(id(n) for n in ast.walk(f)
                                   if isinstance(n, (ast.Import, ast.ImportFrom)))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                found = [t for t in _targets(mods, name, node) if t != name]
                edges[name].update(found)
                if found and id(node) in in_function:
                    inner[name] += 1
        edges.setdefault(name, set())
    return dict(edges), dict(inner)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module, largest first (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
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
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return sorted(out, key=len, reverse=True)


def type_name_tests(root: Path) -> list[tuple[str, int]]:
    """``(file, line)`` of every ``type(x).__name__`` comparison: a kind chosen by a type's name
    instead of :func:`iwr.kinds.of`."""
    out = []
    for path in modules(root).values():
        if path.suffix == ".pyi":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (isinstance(node, ast.Compare) and isinstance(node.left, ast.Attribute)
                    and node.left.attr == "__name__" and isinstance(node.left.value, ast.Call)
                    and getattr(node.left.value.func, "id", None) == "type"):
                out.append((str(path.relative_to(root)), node.lineno))
    return out


def main(argv: list[str]) -> int:
    root = Path(argv[1] if len(argv) > 1 else Path(__file__).resolve().parents[1])
    edges, inner = graph(root)
    comps = cycles(edges)
    print(f"{len(edges)} modules, {sum(len(v) for v in edges.values())} imports between them, "
          f"{sum(inner.values())} of them inside functions")
    print(f"{len(comps)} import cycles (strongly connected components):")
    for comp in comps:
        print(f"  {len(comp):3d} modules: {', '.join(comp)}")
    named = type_name_tests(root)
    print(f"{len(named)} type-name tests" + "".join(f"\n  {f}:{n}" for f, n in named))
    return 1 if named else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
