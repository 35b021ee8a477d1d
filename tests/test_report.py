"""Report sections of evaluations (``mocapnet.evaluate.report``)."""

from __future__ import annotations

import math

import pytest

from mocapnet.evaluate.harness import GAUSSIANS, Evaluation
from mocapnet.evaluate.report import evaluation_section


@pytest.mark.parametrize("plot", [False, True])
def test_evaluation_section(tmp_path, plot):
    rows = [
        {"method": m, "corruption": "angular-0.5", "file": f"clip{k}", "repeat": 0, "angle_err_deg": 1.0 + i + k,
         "gap_err_deg": math.nan, "rot_err_deg": 1.0, "pos_err_cm": 1.0, "point_err_cm": math.nan, "frames": 10,
         "seconds": 0.1}
        for i, m in enumerate(("noisy", *GAUSSIANS)) for k in range(2)
    ]  # fmt: skip
    ev = Evaluation("x", "angular-0.5", "angles", ["noisy", *GAUSSIANS], rows, [("clip9", "too short")])
    lines = evaluation_section(ev, tmp_path / "x_angular-0.5.png" if plot else None)
    assert lines[1] == "## x: angular-0.5 (2 clips)"
    assert "| gaussian-58ms | 2.500 |" in lines[3]
    assert lines[-1] == "- skipped clip9: too short"
    assert ("![error per motion](x_angular-0.5.png)" in lines) == plot
    assert (tmp_path / "x_angular-0.5.png").exists() == plot
