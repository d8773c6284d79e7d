"""The import graph of the iwr package, read with ``ast`` (nothing is imported): its cycles
(strongly connected components), its imports against the declared layer order (:data:`LAYERS`),
the hooks by which a lower layer calls a higher one by name, and where a module tests the type
of its data by name.

    python tools/layers.py [REPO]    # a report; exit 1 on a cycle, an upward import, a module
                                     # missing from LAYERS, a broken hook or a type-name test

Every import counts, at module level, inside a function or under ``if TYPE_CHECKING`` (a
function-level import only defers the cycle it closes). A module may import its own layer and
those below it; a cycle within a layer is still a cycle. The one sanctioned way up is a
registered hook, imported by its dotted name on first use: the kinds' registry
(``register("pose", "iwr.kinds.pose:PoseKind")``) and ``iwr._hooks.HOOKS``; this tool checks
that each names a module of a higher (or the same) layer and an attribute defined there.
"""

from __future__ import annotations

import ast
import re
import sys
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

#: The layers of iwr, lowest first: ``(name, modules)``; a module may import its own layer and
#: those below. An entry is a module's dotted name, or ``"package.*"`` for every module under
#: that package not listed by name; every module of iwr must match one (its package's
#: ``__init__`` is listed by the package's own name).
LAYERS: list[tuple[str, list[str]]] = [
    ("base: compiled core, noise, rotations, files, misclosures, base parameters", [
        "iwr._core", "iwr._blas", "iwr._io", "iwr._hooks", "iwr._registry", "iwr._startup",
        "iwr.noise", "iwr.base_parameters",
        "iwr.transforms", "iwr.misclosures", "iwr.effects", "iwr.effects.builtin",
        "iwr.effects.carriage", "iwr.effects.carriage_thermal",
        "iwr.effects.model"]),
    ("kinds: the measurement-kind protocol and registry", ["iwr.kinds"]),
    ("data and the robot model", [
        "iwr.measurements", "iwr.robot", "iwr.robot_file", "iwr.robot_fingerprint",
        "iwr.tracker.setup", "iwr.tracker.data", "iwr.tracker.files", "iwr.tracker.sa_export",
        "iwr.ballbar.setup", "iwr.ballbar.data", "iwr.ballbar.files"]),
    ("problems: the objective, the implicit loop, the result type", [
        "iwr.implicit_loop", "iwr.problem_base", "iwr.problem", "iwr.tracker.problem",
        "iwr.tracker.registration", "iwr.tracker.gauge", "iwr.tracker.start", "iwr.ballbar.problem",
        "iwr.methods.reduced", "iwr.result", "iwr.effects.problem", "iwr.effects.loop",
        "iwr.effects.gravity", "iwr.effects.tracker_objective"]),
    ("the problem file (iwr-engine's input and result)", ["iwr.problem_file"]),
    ("solvers, the efficient estimator and the fit test", [
        "iwr.methods.*", "iwr.estimator_spec", "iwr.estimation", "iwr.fit_test",
        "iwr.accuracy_prediction",
        "iwr.tracker.estimation", "iwr.effects.solver"]),
    ("public functions: identify, accuracy, identifiability, uncertainty, planning, simulate", [
        "iwr.methods", "iwr.analysis", "iwr.analysis.*", "iwr.planning", "iwr.simulation",
        "iwr.forward", "iwr.pose_frame", "iwr.compensation", "iwr.gross_errors",
        "iwr.tracker", "iwr.tracker.*", "iwr.ballbar", "iwr.ballbar.*", "iwr.export",
        "iwr.export.*", "iwr.effects.api", "iwr.effects.estimation", "iwr.effects.job",
        "iwr.effects.tracker", "iwr.effects.tracker_diagnosis"]),
    ("kind implementations (reached through the kinds' registry)", [
        "iwr.kinds.pose", "iwr.tracker.kind", "iwr.ballbar.kind"]),
    ("the calibration job", ["iwr.calibration"]),
    ("experiments", ["iwr.experiments", "iwr.experiments.*", "iwr.effects.study",
                     "iwr.effects.tracker_study"]),
    ("reports", ["iwr.reporting", "iwr.reporting.*"]),
    ("command line", ["iwr.cli", "iwr.cli.*", "iwr.__main__"]),
    ("the package's public names", ["iwr"]),
]


class Import(NamedTuple):
    """One import of an iwr module by another."""

    source: str
    target: str
    line: int
    in_function: bool
    via: str = ""  # the package whose initialiser imports ``target`` (see :func:`imports`)


def layer_of(module: str, layers: list[tuple[str, list[str]]] | None = None) -> int | None:
    """The index of ``module``'s layer in ``layers`` (default :data:`LAYERS`): the entry naming
    it, else the longest ``"package.*"`` entry above it; None when none does."""
    exact, prefix = {}, {}
    for i, (_, entries) in enumerate(LAYERS if layers is None else layers):
        for e in entries:
            if e.endswith(".*"):
                prefix[e[:-2]] = i
            else:
                exact[e] = i
    if module in exact:
        return exact[module]
    parts = module.split(".")
    for n in range(len(parts) - 1, 0, -1):
        if ".".join(parts[:n]) in prefix:
            return prefix[".".join(parts[:n])]
    return None


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


def imports(root: Path) -> list[Import]:
    """Every import of an iwr module by another, with its line and whether it sits in a
    function."""
    mods = modules(root)
    out = []
    for name, path in mods.items():
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
                for t in dict.fromkeys(_targets(mods, name, node)):
                    if t != name:
                        out.append(Import(name, t, node.lineno, id(node) in in_function))
    # Importing p.q.m runs p/q/__init__.py first (from outside p.q): what that initialiser
    # imports at run time, the importer imports too. (Not the root package's, iwr/__init__.py:
    # every module is inside it; it holds the public names and sits in the top layer.)
    runtime = {p: _runtime_imports(mods, p) for p in mods if mods[p].name == "__init__.py"}
    for imp in list(out):
        parts = imp.target.split(".")
        for n in range(2, len(parts)):
            package = ".".join(parts[:n])
            if imp.source == package or imp.source.startswith(package + "."):
                continue
            out += [Import(imp.source, t, imp.line, imp.in_function, package)
                    for t in runtime.get(package, ()) if t != imp.source]
    return sorted(set(out))


def _runtime_imports(mods: dict[str, Path], package: str) -> list[str]:
    """The iwr modules that ``package``'s ``__init__`` imports when it runs: at module level,
    not under ``if TYPE_CHECKING``."""
    out = []
    for node in ast.parse(mods[package].read_text()).body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out += [t for t in _targets(mods, package, node) if t != package]
    return out


def graph(root: Path) -> tuple[dict[str, set[str]], dict[str, int]]:
    """``(edges, inner)``: module -> the iwr modules it imports; module -> how many of its
    imports sit inside functions."""
    edges: dict[str, set[str]] = {name: set() for name in modules(root)}
    inner: dict[str, int] = defaultdict(int)
    seen = set()
    for imp in imports(root):
        edges[imp.source].add(imp.target)
        if imp.in_function and (imp.source, imp.line) not in seen:
            seen.add((imp.source, imp.line))
            inner[imp.source] += 1
    return edges, dict(inner)


def unlisted(root: Path, layers: list[tuple[str, list[str]]] | None = None) -> list[str]:
    """The modules of iwr that ``layers`` (default :data:`LAYERS`) does not place."""
    return [m for m in modules(root) if layer_of(m, layers) is None]


def upward(root: Path, layers: list[tuple[str, list[str]]] | None = None) -> list[Import]:
    """Every import from a lower layer to a higher one (module level, in a function, or through
    a package's initialiser) against ``layers`` (default :data:`LAYERS`)."""
    out = []
    for imp in imports(root):
        a, b = layer_of(imp.source, layers), layer_of(imp.target, layers)
        if a is not None and b is not None and b > a:
            out.append(imp)
    return out


_DOTTED = re.compile(r"iwr(\.\w+)+:\w+")


def hooks(root: Path) -> list[tuple[str, int, str]]:
    """``(file, line, "module:attribute")`` of every name by which iwr imports a module on first
    use: each string of that form in its modules (the kinds' registry,
    ``register("pose", "iwr.kinds.pose:PoseKind")``; a kind's ``report``; the values of
    ``iwr._hooks.HOOKS``)."""
    out = []
    for path in modules(root).values():
        if path.suffix == ".pyi":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and _DOTTED.fullmatch(node.value)):
                out.append((str(path.relative_to(root)), node.lineno, node.value))
    return sorted(out)


def _defines(path: Path, name: str) -> bool:
    """Whether module ``path`` binds ``name`` at its top level (def, class, assignment, import)."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            if node.name == name:
                return True
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(getattr(t, "id", None) == name for t in targets):
                return True
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            if any((a.asname or a.name.split(".")[0]) == name for a in node.names):
                return True
    return False


def broken_hooks(root: Path) -> list[str]:
    """Hooks that name no module of iwr, no attribute defined in it, or a module of a lower
    layer than the one that registers them (a hook is for reaching up, not a hidden import)."""
    mods = modules(root)
    out = []
    for file, line, spec in hooks(root):
        module, _, attribute = spec.partition(":")
        owner = ".".join(Path(file).with_suffix("").parts).removesuffix(".__init__")
        if module not in mods:
            out.append(f"{file}:{line}: {spec}: no module {module}")
        elif not attribute or not _defines(mods[module], attribute):
            out.append(f"{file}:{line}: {spec}: {module} defines no {attribute!r}")
        elif (layer_of(module) or 0) < (layer_of(owner) or 0):
            out.append(f"{file}:{line}: {spec}: {module} is below {owner}; import it")
    return out


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


def _top_level(body: list[ast.stmt]) -> list[ast.stmt]:
    """The statements of a module body, those inside its ``if`` and ``try`` blocks included."""
    out = []
    for node in body:
        out.append(node)
        for block in ("body", "orelse", "finalbody", "handlers"):
            inner = getattr(node, block, None)
            if isinstance(node, (ast.If, ast.Try, ast.ExceptHandler)) and inner:
                out += _top_level(inner)
    return out


def shadowed(root: Path) -> list[str]:
    """``package.name`` for every submodule of a package that the package's ``__init__`` binds
    to something else (a function of the same name, say): ``package.name`` is then the function
    until something imports the submodule, which rebinds it. Names bound by an import (also under
    ``if TYPE_CHECKING``), a def, a class, an assignment, or a key of a lazy table (``_LAZY``)."""
    mods = modules(root)
    out = []
    for package, path in mods.items():
        if path.name != "__init__.py":
            continue
        subs = {m.rsplit(".", 1)[1] for m in mods if m.rpartition(".")[0] == package}
        bound: set[str] = set()
        for node in _top_level(ast.parse(path.read_text()).body):
            if isinstance(node, ast.ImportFrom):
                submodule_itself = node.level == 1 and node.module is None
                bound.update(a.asname or a.name for a in node.names
                             if not (submodule_itself and (a.asname or a.name) == a.name))
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                bound.add(node.name)
            elif isinstance(node, ast.Assign):
                bound.update(t.id for t in node.targets if isinstance(t, ast.Name))
                if (any(getattr(t, "id", None) == "_LAZY" for t in node.targets)
                        and isinstance(node.value, ast.Dict)):
                    bound.update(k.value for k in node.value.keys
                                 if isinstance(k, ast.Constant) and isinstance(k.value, str))
        out += [f"{package}.{name}" for name in sorted(bound & subs)]
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
    missing = unlisted(root)
    counts = defaultdict(int)
    for m in edges:
        counts[layer_of(m)] += 1
    print(f"{len(LAYERS)} layers (lowest first; modules in each); {len(missing)} modules not in "
          "the table" + "".join(f"\n  {i:2d} {name.split(':')[0]}: {counts[i]}"
                               for i, (name, _) in enumerate(LAYERS))
          + "".join(f"\n  not in the table: {m}" for m in missing))
    up = upward(root)
    print(f"{len(up)} upward imports" + "".join(
        f"\n  {i.source} ({LAYERS[layer_of(i.source) or 0][0].split(':')[0]}) -> {i.target} "
        f"({LAYERS[layer_of(i.target) or 0][0].split(':')[0]}), line {i.line}"
        f"{' in a function' if i.in_function else ''}"
        f"{f', through the initialiser of {i.via}' if i.via else ''}" for i in up))
    found = hooks(root)
    broken = broken_hooks(root)
    print(f"{len(found)} registered hooks (a lower layer reaching up by name), "
          f"{len(broken)} broken" + "".join(f"\n  {b}" for b in broken))
    hidden = shadowed(root)
    print(f"{len(hidden)} submodules shadowed by a name of their package"
          + "".join(f"\n  {m}" for m in hidden))
    named = type_name_tests(root)
    print(f"{len(named)} type-name tests" + "".join(f"\n  {f}:{n}" for f, n in named))
    return 1 if (comps or missing or up or broken or hidden or named) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
