"""``iwr/_core.pyi``, the stub of the compiled module, says what ``iwr._core`` exports: the same
names both ways, the same members of each class, and the same parameters (names, and which have
defaults) as the signatures pybind11 writes in each function's docstring. A binding added, renamed
or removed in ``cpp/python`` without the stub fails here (the stub had lost four bindings and a
method, and listed an ``__all__`` the module does not have)."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

from iwr import _core

STUB = Path(__file__).resolve().parents[1] / "iwr" / "_core.pyi"
# pybind11's own attribute of every bound class (its cross-module conduit), not an API
PYBIND_INTERNAL = {"_pybind11_conduit_v1_"}


def _stub() -> dict[str, ast.stmt]:
    out: dict[str, ast.stmt] = {}
    for node in ast.parse(STUB.read_text()).body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            out[node.name] = node
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out[node.target.id] = node
        elif isinstance(node, ast.Assign):
            out.update({t.id: node for t in node.targets if isinstance(t, ast.Name)})
    return out


def _dunder(name: str) -> bool:
    return name.startswith("__") and name.endswith("__")


def _exported() -> set[str]:
    return {n for n in dir(_core) if not _dunder(n)}


def _members(cls: type) -> set[str]:
    return {n for n in vars(cls) if (not _dunder(n) or n == "__init__")} - PYBIND_INTERNAL


def _params(args: ast.arguments) -> list[tuple[str, bool]]:
    """(name, has a default) of each parameter but self."""
    pos = args.posonlyargs + args.args
    first_default = len(pos) - len(args.defaults)
    out = [(a.arg, i >= first_default) for i, a in enumerate(pos)]
    out += [(a.arg, d is not None) for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True)]
    return [p for p in out if p[0] != "self"]


def _bound_params(obj: object) -> list[tuple[str, bool]] | None:
    """The parameters of pybind11's signature line, or None without one (a plain class)."""
    doc = inspect.getdoc(obj) or ""
    line = doc.split("\n", 1)[0]
    name = getattr(obj, "__name__", "")
    if not line.startswith(name + "("):
        return None
    head = line.rsplit(" -> ", 1)[0]
    return _params(ast.parse(f"def {head}: pass").body[0].args)


def test_the_stub_has_every_export_of_the_module():
    missing = sorted(_exported() - set(_stub()))
    assert not missing, f"iwr._core exports {missing}, which iwr/_core.pyi lacks"


def test_the_module_has_every_name_of_the_stub():
    extra = sorted(set(_stub()) - _exported())
    assert not extra, f"iwr/_core.pyi has {extra}, which iwr._core does not export"


@pytest.mark.parametrize("name", sorted(n for n, v in _stub().items()
                                        if isinstance(v, ast.ClassDef)))
def test_a_class_has_the_stubs_members(name):
    node = _stub()[name]
    stub = {m.name for m in node.body if isinstance(m, ast.FunctionDef)}
    cls = getattr(_core, name)
    if issubclass(cls, BaseException):  # a bound exception: Python's own members
        assert not stub, f"{name}: the stub gives an exception members {sorted(stub)}"
        return
    assert stub == _members(cls), (f"{name}: only in the stub {sorted(stub - _members(cls))}, "
                                   f"only in the module {sorted(_members(cls) - stub)}")
    for m in node.body:
        if isinstance(m, ast.FunctionDef) and not any(
                isinstance(d, ast.Name) and d.id == "property" for d in m.decorator_list):
            bound = _bound_params(getattr(cls, m.name))
            assert bound is not None, f"{name}.{m.name}: no pybind11 signature to compare"
            assert _params(m.args) == bound, f"{name}.{m.name}: the stub's parameters differ"


@pytest.mark.parametrize("name", sorted(n for n, v in _stub().items()
                                        if isinstance(v, ast.FunctionDef)))
def test_a_function_has_the_stubs_parameters(name):
    bound = _bound_params(getattr(_core, name))
    assert bound is not None, f"{name}: no pybind11 signature to compare"
    assert _params(_stub()[name].args) == bound, f"{name}: the stub's parameters differ"
