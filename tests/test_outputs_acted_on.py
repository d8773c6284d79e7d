"""Outputs a calibration engineer acts on: what a report says of a result identified elsewhere
(``iwr report`` of an ``iwr-calibrate`` run), the status a calibration file records."""

from __future__ import annotations

import numpy as np

import iwr
from iwr.calibration import from_result
from iwr.result import IdentificationResult


def test_a_stopped_run_is_not_screened_for_gross_errors():
    """A DE run that a limit stopped before it converged: the residuals of its best point hold
    what it has not fitted yet, and the test of each pose blamed clean poses for them (a
    ballbar run with effects stopped at 30 generations: 2 clean poses named, "THE MODEL DOES
    NOT FIT THE DATA", exit 3). Not tested, and said so; the verdict is "not converged"."""
    robot = iwr.Robot.default()
    data, truth = iwr.simulate(robot, 20, seed=3, noise=iwr.Noise.realistic())
    res = IdentificationResult(
        x=0.5 * truth, fun=1.0, nfev=100, nit=10, success=False, status="stopped",
        message="the maximum number of generations (30) was reached", method="de",
        parameter_names=robot.parameter_names, settings={}, history={})
    cal = from_result(robot, data, res)
    assert cal.result.outliers is None and cal.fit_ok is None
    assert cal.result.gross_errors.startswith("gross errors: not tested (the method stopped "
                                              "before it converged")
    from iwr.reporting.calibration import render

    report = render(cal)
    assert "gross errors: not tested (the method stopped" in report.text()
    assert report.status_text() == "not converged (status stopped)"
    # A converged result at the same point is tested.
    done = IdentificationResult(**{**dict(res), "success": True, "status": "converged",
                                   "message": "converged", "x": np.asarray(truth)})
    assert from_result(robot, data, done).result.outliers is not None
