"""Short commands start fast (issue 24): ``import iwr`` and ``iwr --help`` import neither SciPy
nor importlib.metadata; every public name still resolves, to the same object as its module's."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import iwr

HEAVY = ("scipy", "matplotlib", "nlopt", "tqdm", "importlib.metadata")


def _loaded(code: str, tmp_path) -> list[str]:
    """The heavy packages a fresh interpreter has loaded after running ``code``."""
    probe = (f"{code}\nimport sys, json\n"
             f"print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r} "
             f"or m == 'importlib.metadata')))")
    # cwd: not the repository root, whose source folder has no compiled module
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_import_iwr_loads_nothing_heavy(tmp_path):
    assert _loaded("import iwr", tmp_path) == []


def test_help_loads_nothing_heavy(tmp_path):
    """(``iwr compare --help`` lists the registered methods: it imports them, when shown.)"""
    code = ("import contextlib, io, iwr.cli\n"
            "for argv in (['--help'], ['calibrate', '--help'], ['plan', '--help']):\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        try:\n            iwr.cli.main(argv)\n        except SystemExit:\n"
            "            pass\n")
    assert _loaded(code, tmp_path) == []


def test_the_probe_sees_a_heavy_import(tmp_path):
    """The check above is not blind: a name that needs SciPy loads it."""
    assert "scipy" in _loaded("import iwr\niwr.identify", tmp_path)


def test_every_public_name_resolves_to_its_module_object():
    for name in iwr.__all__:
        assert getattr(iwr, name) is not None, name
    import iwr.methods as methods

    assert iwr.identify is methods.identify
    de = importlib.import_module("iwr.methods.de")
    assert iwr.differential_evolution is de.differential_evolution
    assert iwr.study is importlib.import_module("iwr.experiments.monte_carlo").study
    assert iwr.__version__ == importlib.import_module("iwr.reporting.html").iwr_version()
    assert "identify" in dir(iwr)


def test_public_functions_stay_functions_once_their_modules_are_imported():
    """No module is named like the function its package exports (tools/layers.py checks it):
    importing the module that defines a public function leaves the package's name the function."""
    for module, name in (("iwr.simulation", "simulate"), ("iwr.analysis.accuracy", "accuracy"),
                         ("iwr.analysis.identifiability", "identifiability"),
                         ("iwr.analysis.uncertainty", "uncertainty")):
        assert getattr(iwr, name) is getattr(importlib.import_module(module), name), name
    experiments = importlib.import_module("iwr.experiments")
    studies = importlib.import_module("iwr.experiments.monte_carlo")
    assert experiments.study is studies.study is iwr.study


def test_an_unknown_name_is_an_attribute_error():
    try:
        iwr.no_such_name  # noqa: B018
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:
        raise AssertionError("no AttributeError")


def test_version_option_prints_the_version(capsys):
    from iwr.cli import main

    try:
        main(["--version"])
    except SystemExit as exc:
        assert exc.code in (0, None)
    kernels = ", ".join(iwr._core._supported_kernels())
    assert capsys.readouterr().out.strip() == (
        f"iwr {iwr.__version__} (kernel {iwr._core._active_kernel()}; this CPU runs {kernels})")
