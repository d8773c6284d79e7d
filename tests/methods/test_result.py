"""The one result type: status and success, the JSON file (also written by iwr-calibrate), and
results that are not finite."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import OptimizeResult

import iwr
from iwr.methods import STATUSES, IdentificationResult


def result(**kw):
    base = dict(x=np.arange(3.0), fun=1.5, nfev=10, nit=2, success=True, message="ok",
                method="lm", parameter_names=["a", "b", "c"], history={"nfev": [1, 10],
                                                                       "best": [3.0, 1.5]})
    return IdentificationResult(**{**base, **kw})


def test_an_optimize_result_with_declared_attributes():
    r = result()
    assert isinstance(r, OptimizeResult)
    assert r.status == "converged" and r.success and not r.interrupted
    assert r.named() == {"a": 0.0, "b": 1.0, "c": 2.0}
    assert r.settings == {} and r.active is None and np.isnan(r.wall_time)
    assert not result(success=False).success and result(success=False).status == "stopped"
    stopped = result(success=True, status="interrupted", message="interrupted (Ctrl-C)")
    assert not stopped.success and stopped.interrupted
    with pytest.raises(ValueError, match="status: 'done'"):
        result(status="done")
    assert set(STATUSES) == {"converged", "stopped", "callback", "interrupted", "failed",
                             "not calibrated"}
    # A result file keeps success and message: the judgement of a calibration survives it.
    from iwr.result import status_from_message

    assert status_from_message(False, "not calibrated: degenerate data: ...") == "not calibrated"
    assert "status: converged" in repr(result(settings={}, history={}))  # SciPy's fails there


@pytest.mark.parametrize("x, fun", [([np.nan, 0.0, 0.0], 1.0), ([0.0, 0.0, 0.0], np.inf),
                                    ([0.0, 0.0, 0.0], np.nan)])
def test_not_finite_is_never_a_success(x, fun):
    r = result(x=x, fun=fun)
    assert not r.success and r.status == "failed" and "not finite" in r.message


def test_file_round_trip_keeps_the_keys(tmp_path):
    r = result(settings={"seed": 3, "tol": np.float64(0.5)}, wall_time=0.25)
    r.save(tmp_path / "r.json")
    data = json.loads((tmp_path / "r.json").read_text())
    assert set(data) == {"format", "version", "method", "x", "parameter_names", "fun", "nfev",
                         "nit", "success", "status", "message", "wall_time", "settings",
                         "history"}
    back = iwr.load_result(tmp_path / "r.json")
    np.testing.assert_array_equal(back.x, r.x)
    assert (back.fun, back.nfev, back.nit, back.success, back.status, back.method) == \
        (1.5, 10, 2, True, "converged", "lm")
    assert back.settings == {"seed": 3, "tol": 0.5}
    np.testing.assert_array_equal(back.history["best"], [3.0, 1.5])


def test_a_cost_that_is_not_finite_is_written_null_and_loads(tmp_path):
    """iwr-calibrate writes "fun": null for a cost that is not finite; it loads, as a failure."""
    r = result(fun=np.inf)
    r.save(tmp_path / "r.json")
    text = (tmp_path / "r.json").read_text()
    assert '"fun": null' in text and "Infinity" not in text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    back = iwr.load_result(tmp_path / "r.json")
    assert np.isnan(back.fun) and not back.success and back.status == "failed"
    data = json.loads(text)
    data.update(success=True, status="converged", x=[None, 1.0, 2.0], fun=0.5)
    (tmp_path / "c.json").write_text(json.dumps(data))
    back = iwr.load_result(tmp_path / "c.json")
    assert np.isnan(back.x[0]) and not back.success


@pytest.mark.parametrize("message, status", [
    ("interrupted by SIGINT at generation 3", "interrupted"),
    ("stopped by the callback", "callback"),
    ("the maximum number of generations (5) was reached", "stopped"),
])
def test_status_of_a_loaded_unsuccessful_result(tmp_path, message, status):
    """A file of an older iwr records no status: it is read from the message."""
    result(success=False, message=message).save(tmp_path / "r.json")
    data = json.loads((tmp_path / "r.json").read_text())
    del data["status"]
    (tmp_path / "r.json").write_text(json.dumps(data))
    assert iwr.load_result(tmp_path / "r.json").status == status


@pytest.mark.parametrize("status", sorted(set(STATUSES) - {"converged"}) + ["converged"])
def test_a_file_keeps_the_status_of_an_unsuccessful_result(tmp_path, status):
    """A run that converged to a point whose model does not fit the data (success False,
    status "converged") was read back as "stopped", so ``iwr report`` of an ``iwr calibrate``
    run that had said "the model does not fit the data" said "not converged ... (run it longer
    first)". The file records the status now; every status reads back as written."""
    result(success=False, status=status,
           message="the model does not fit the data").save(tmp_path / "r.json")
    back = iwr.load_result(tmp_path / "r.json")
    assert (back.status, back.success) == (status, False)


def test_bad_files_are_named(tmp_path):
    (tmp_path / "r.json").write_text('{"format": "iwr-result", "x": [1, "a"], "fun": 1, '
                                     '"nfev": 1, "success": true, "message": ""}')
    with pytest.raises(iwr.ResultFileError,
                       match=r"r.json: x\[1\]: expected a number or null, got 'a'"):
        iwr.load_result(tmp_path / "r.json")
    with pytest.raises(iwr.ResultFileError, match="no such file"):
        iwr.load_result(tmp_path / "missing.json")


def test_optional_fields_are_typed_attributes_that_read_none():
    """What a method may add (iwr.result.OPTIONAL_FIELDS) reads None when it did not, and a
    name that is no field still raises AttributeError (a typo is not silently None)."""
    from iwr.result import OPTIONAL_FIELDS

    r = result()
    for name in OPTIONAL_FIELDS:
        assert getattr(r, name) is None, name
    assert r.fit_ok is None and r.left_out == []
    with pytest.raises(AttributeError, match="fitt"):
        r.fitt  # noqa: B018
    assert "fit" not in r  # absent stays absent (the dictionary is SciPy's)


def test_the_file_keeps_the_fit_test_and_the_poses_left_out(tmp_path):
    """A result file records the fit test and the outliers with their file lines: what `iwr
    report` needs to leave out the poses the run left out."""
    from iwr.result import FitTest, Outlier

    fit = FitTest(12.5, 10, 0.25, 1e-3, False, "THE MODEL DOES NOT FIT", ["a cause"],
                  [("b", 3.0, 1.0)])
    outliers = [Outlier(4, "m.csv, line 7", 30.0, 6, 1e-6, "leg3", 5.1, True, ("q1",),
                        line=7),
                Outlier(2, "pose 2", 20.0, 6, 1e-4, "q2", -4.0, False, data_set="validation",
                        test="tau")]
    r = result(fit=fit, outliers=outliers, gross_errors="gross errors: Pope's test")
    assert r.fit_ok is False and [o.line for o in r.left_out] == [7]
    r.save(tmp_path / "r.json")
    back = iwr.load_result(tmp_path / "r.json")
    assert back.fit == fit and back.outliers == outliers
    assert back.gross_errors == "gross errors: Pope's test"
    # A fit test without a statistic (no redundancy) is written null, as strict JSON, and reads NaN.
    nan_fit = FitTest(float("nan"), 0, float("nan"), 1e-3, False, "no redundancy")
    result(fit=nan_fit).save(tmp_path / "n.json")
    json.loads((tmp_path / "n.json").read_text(),
               parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert np.isnan(iwr.load_result(tmp_path / "n.json").fit.statistic)
    data = json.loads((tmp_path / "r.json").read_text())
    data["outliers"][0]["line"] = "seven"
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(iwr.ResultFileError,
                       match=r"bad.json: outliers\[0\].line: expected an integer, got 'seven'"):
        iwr.load_result(tmp_path / "bad.json")
    data["outliers"][0] = {"pose": 1, "colour": "red"}
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(iwr.ResultFileError, match=r"bad.json: outliers\[0\]: expected an object"):
        iwr.load_result(tmp_path / "bad.json")
    del data["outliers"]
    del data["fit"]["dof"]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(iwr.ResultFileError, match="bad.json: missing key 'dof'"):
        iwr.load_result(tmp_path / "bad.json")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["fit"].update(fit_ok="false"), r"fit.fit_ok: expected true or false"),
    (lambda d: d["outliers"][0].update(removed="no"), r"outliers\[0\].removed: expected true"),
    (lambda d: d["outliers"][0].update(data_set="validaton"), r"data_set: 'validaton'"),
    (lambda d: d["fit"].update(dof=2.7), r"fit.dof: expected an integer, got 2.7"),
    (lambda d: d["fit"].pop("statistic"), r"missing key 'statistic'"),
    (lambda d: d["fit"].update(causes="abc"), r"fit.causes, fit.implausible: expected lists"),
    (lambda d: d.update(gross_errors=5), r"gross_errors: expected a string, got 5"),
    (lambda d: d["outliers"][0].pop("where"), r"outliers\[0\]: missing \['where'\]"),
])
def test_recorded_values_of_the_wrong_type_are_named(tmp_path, edit, message):
    """The review's cases: a recorded value of the wrong type is refused by name, never read
    as something else ("false" as True, "no" as removed, "abc" as three causes)."""
    from iwr.result import FitTest, Outlier

    r = result(fit=FitTest(12.5, 10, 0.25, 1e-3, True, "fits"), gross_errors="screened",
               outliers=[Outlier(4, "m.csv, line 7", 30.0, 6, 1e-6, "leg3", 5.1, True,
                                 line=7, key="ab")])
    r.save(tmp_path / "r.json")
    data = json.loads((tmp_path / "r.json").read_text())
    edit(data)
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(iwr.ResultFileError, match=message):
        iwr.load_result(tmp_path / "bad.json")


@pytest.mark.parametrize("edit, message", [
    # A QA audit: "false" read as True, an unknown status as "converged": the report said
    # "Calibrated" of a run that had not converged.
    (lambda d: d.update(success="false"), r"success: expected true or false, got 'false'"),
    (lambda d: d.update(status="not converged"), r"status: 'not converged'; expected one of"),
    (lambda d: d.update(status="stopped"),
     r"success: true, but status 'stopped': only a converged run is a success"),
    (lambda d: d.update(status=3), r"status: expected a string, got 3"),
    (lambda d: d.update(message=None), r"message: expected a string, got None"),
    (lambda d: d.update(method=["lm"]), r"method: expected a string"),
    (lambda d: d.update(fun="1.5"), r"fun: expected a number or null, got '1.5'"),
    (lambda d: d.update(nfev=10.5), r"nfev: expected an integer, got 10.5"),
    (lambda d: d.update(nit=-1), r"nit: -1; expected a count >= 0"),
    (lambda d: d.update(wall_time="fast"), r"wall_time: expected a number or null"),
    (lambda d: d.update(version=99), r"version: 99; this iwr reads versions 1 to 1"),
    (lambda d: d.update(x=5), r"x: expected a list of numbers, one per parameter, got 5"),
    (lambda d: d.update(x=[[0.0], [1.0], [2.0]]),
     r"x\[0\] \(a\): expected a number or null, got \[0.0\]"),
    (lambda d: d.update(x=[0.0, True, 2.0]), r"x\[1\] \(b\): expected a number or null, got True"),
    (lambda d: d.update(x=[0.0, 1.0]), r"x: 2 values, but parameter_names names 3 parameters"),
    (lambda d: d.update(parameter_names="abc"), r"parameter_names: expected a list of strings"),
    (lambda d: d.update(parameter_names=["a", 2, "c"]), r"parameter_names\[1\]: expected a str"),
    (lambda d: d.update(parameter_names=["a", "b", "a"]), r"parameter_names: 'a' is named twice"),
    (lambda d: d.update(history=5), r"history: expected an object of lists of numbers, got 5"),
    (lambda d: d.update(history={"best": 1.5}), r"history.best: expected a list of numbers"),
    (lambda d: d.update(history={"best": [1.0, "x"]}), r"history.best\[1\]: expected a number"),
    (lambda d: d.update(history={"nfev": [1, 2.5]}), r"history.nfev\[1\]: expected an integer"),
    (lambda d: d.update(settings=[1, 2]), r"settings: expected an object, got \[1, 2\]"),
    (lambda d: d["settings"].update(sources=["a.csv"]),
     r"settings.sources: expected an object, got \['a.csv'\]"),
    (lambda d: d["settings"].update(sources={"data": 3}),
     r"settings.sources.data: expected a string, got 3"),
    (lambda d: d["settings"].update(data_fingerprint=12),
     r"settings.data_fingerprint: expected a string, got 12"),
    (lambda d: d["settings"].update(robot_model="abc"),
     r"settings.robot_model: expected an object, got 'abc'"),
])
def test_every_field_of_a_result_file_is_typed(tmp_path, edit, message):
    """Every field a result file holds is of its JSON type, and a file that contradicts itself
    (success true, status "stopped") is refused: each named with its file, never read as
    something else nor failing later with an internal error."""
    result(settings={"seed": 3, "data_fingerprint": "ab"}).save(tmp_path / "r.json")
    data = json.loads((tmp_path / "r.json").read_text())
    edit(data)
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(iwr.ResultFileError, match=r"bad.json: " + message):
        iwr.load_result(tmp_path / "bad.json")
    assert iwr.load_result(tmp_path / "r.json").success  # the file before the edit reads
