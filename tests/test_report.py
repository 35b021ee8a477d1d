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


def test_plot_ratios_draws_named_methods_and_refuses_an_ambiguous_name(tmp_path):
    """``plot_ratios``: one panel per corpus; ``ebf-paper`` matches ``ebf-paper=run.ckpt`` when that is the only
    such string; two strings of one name must be named exactly; a name absent from every row is an error."""
    from mocapnet.evaluate.report import plot_ratios

    def row(corpus, corruption, method, ratio):
        return {"corpus": corpus, "corruption": corruption, "method": method, "ratio": ratio}

    rows = [
        row(c, k, m, r)
        for c in ("bandai2", "bandai1")
        for k in ("angular-0.5", "spatial-0.5cm")
        for m, r in (("ebf", 0.85), ("ebf-paper=run.ckpt", 0.9), ("gaussian-58ms", 1.0))
    ]
    out = tmp_path / "ratios.png"
    plot_ratios(rows, ["ebf", "ebf-paper"], out, "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="several method strings"):
        plot_ratios([*rows, row("bandai1", "angular-0.5", "ebf-paper=other.ckpt", 0.8)], ["ebf-paper"], out)
    with pytest.raises(ValueError, match="none of"):
        plot_ratios(rows, ["knn"], out)


def test_a_base_name_is_matched_within_each_corpus():
    """bandai2's exact ``gaussian-tuned`` does not hide bandai1's ``gaussian-tuned:tune_on=bandai2``."""
    from mocapnet.evaluate.report import _drawn_as

    bandai1 = [
        {"corpus": "bandai1", "method": "gaussian-tuned:tune_on=bandai2"},
        {"corpus": "bandai1", "method": "ebf"},
    ]
    assert _drawn_as("gaussian-tuned:tune_on=bandai2", ["gaussian-tuned"], bandai1) == "gaussian-tuned"
    with_exact = [*bandai1, {"corpus": "bandai1", "method": "gaussian-tuned"}]
    assert (
        _drawn_as("gaussian-tuned:tune_on=bandai2", ["gaussian-tuned"], with_exact) == "gaussian-tuned:tune_on=bandai2"
    )
