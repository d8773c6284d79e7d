"""The README's Python example runs as written, and the calibration file it writes is one `iwr
legs` takes (a file written by hand with `to_toml` records no status, and was refused: found by
an outside audit following the README)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from iwr.compensation import check_calibration, leg_commands

README = Path(__file__).resolve().parent.parent / "README.md"


def test_the_readme_python_example_runs_and_writes_a_usable_calibration(tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert blocks, "README.md: no python example"
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        scope: dict = {}
        exec(compile(blocks[0], "README.md", "exec"), scope)  # noqa: S102
    finally:
        os.chdir(here)
    import iwr

    written = iwr.Robot.from_toml(tmp_path / "my-calibration" / "calibrated.toml")
    assert written.provenance["status"] == "success"
    assert check_calibration(written) == ""
    data = scope["data"]
    cmd = leg_commands(written, data.q[:5], data.poses[:5])
    # The noise of the readings (realistic: a few micrometres) is all that separates them.
    assert np.abs(cmd.legs - data.legs[:5]).max() < 0.1
    assert scope["calibrated"].n_params == written.n_params
