"""Tests of the kNN benchmark's bookkeeping (mocapnet.evaluate.knn_bench): the selection rule and the verdicts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocapnet.evaluate import knn_bench
from mocapnet.evaluate.knn_bench import TUNE_CORRUPTIONS, TUNE_VARIANTS, evenly, tune_scores, variant_name, verdicts
from mocapnet.methods.knn_angles import ANGLE_DEFAULTS
from mocapnet.methods.knn_window import Searcher, WindowSettings


def _row(method: str, corruption: str, pos: float, gap: float, **extra: object) -> dict:
    return {"method": method, "corruption": corruption, "file": "a", "pos_err_cm": pos, "gap_err_deg": gap, **extra}


def test_selection_rule_takes_the_worse_of_position_and_angle_ratios() -> None:
    """Score per cell = max(pos / better of lerp and pca, gap / lerp); a variant twice as good as lerp in
    position but no better than pca scores 1 there."""
    rows = []
    for c in TUNE_CORRUPTIONS:
        for mode in ("in", "out"):
            rows += [_row("lerp", c, 2.0, 10.0, mode=mode), _row("pca", c, 1.0, 8.0, mode=mode)]
            for i, v in enumerate(TUNE_VARIANTS):
                rows.append(_row(variant_name(v), c, 1.0 + 0.1 * i, 5.0 if i else 12.0, mode=mode))
    scores = tune_scores(rows)
    assert scores["defaults"] == 1.2  # gap 12 / lerp 10 beats pos 1.0 / pca 1.0
    assert scores[variant_name(TUNE_VARIANTS[1])] == 1.1  # pos 1.1 / 1.0 beats gap 0.5
    assert min(scores, key=scores.get) == variant_name(TUNE_VARIANTS[1])
    angles = knn_bench.tune_angle_ratios(rows)  # the guard: mean of gap / lerp over the cells
    assert angles["defaults"] == 1.2 and angles[variant_name(TUNE_VARIANTS[1])] == 0.5
    text = knn_bench.tune_markdown(rows, {"command": "c", "git_commit": "g", "machine": "m", "wall_s": 1.0})
    table = [line for line in text.splitlines() if line.startswith("| ")]
    assert len(table) == 1 + 2 + len(TUNE_VARIANTS) and table[3].endswith("| 1.200 |")  # header, lerp, pca, ...


def test_verdicts_compare_knn_with_the_better_baseline() -> None:
    bvh = [
        {**_row(m, c, pos, 0.0), "corpus": "bandai1", "angle_err_deg": ang}
        for c in knn_bench.DONE_WHEN
        for m, pos, ang in (("knn", 0.9, 1.0), ("lerp", 2.0, 2.0), ("pca", 0.8, 3.0))
    ]
    c3d = [
        {"method": m, "gap_s": s, "point_err_cm": e}
        for s in knn_bench.GAP_SECONDS
        for m, e in zip(knn_bench.C3D_METHODS, (1.0, 5.0, 2.0, 3.0, 4.0))
    ]
    lines = verdicts(bvh, c3d, {"per_gap": {"1": 0.1, "8": 0.3}})
    assert all("**missed**" in line for line in lines[:3])  # pca 0.8 beats knn 0.9 in position
    assert all("**met**" in line for line in lines[3:6]) and "**missed**" in lines[6]  # 0.3 s/s > 0.2
    assert evenly(list(range(10)), 3) == [0, 4, 9] and evenly([1], 5) == [1] and evenly([], 2) == []


def test_merge_parts_keeps_the_parts_not_rerun_and_says_which_run_made_each() -> None:
    run = {"command": "old", "git_commit": "a", "machine": "m", "wall_s": 9.0, "n_clips": 60, "repeats": 1}
    previous = {
        **run,
        "bvh": [{"corpus": "bandai2", "x": 1}, {"corpus": "bandai1", "x": 2}],
        "c3d": [{"x": 3}],
        "speed": {"per_gap": {"1": 0.1}},
    }
    fresh = {"bvh": [{"corpus": "bandai1", "x": 4}], "speed": {"per_gap": {"1": 0.2}}}
    new_run = {**run, "command": "new", "git_commit": "b"}
    merged = knn_bench.merge_parts(previous, fresh, ["bandai1", "speed"], new_run)
    assert merged["bvh"] == [{"corpus": "bandai2", "x": 1}, {"corpus": "bandai1", "x": 4}]
    assert merged["c3d"] == [{"x": 3}] and merged["speed"] == {"per_gap": {"1": 0.2}}
    assert [(r["git_commit"], r["parts"]) for r in merged["runs"]] == [
        ("a", ["bandai2", "c3d"]),
        ("b", ["bandai1", "speed"]),
    ]
    again = knn_bench.merge_parts(merged, {"c3d": []}, ["c3d"], {**new_run, "git_commit": "c"})
    assert [(r["git_commit"], r["parts"]) for r in again["runs"]] == [
        ("a", ["bandai2"]),
        ("b", ["bandai1", "speed"]),
        ("c", ["c3d"]),
    ]
    with pytest.raises(ValueError, match="no earlier report"):
        knn_bench.merge_parts(None, fresh, ["bandai1", "speed"], new_run)
    with pytest.raises(ValueError, match="parts must be among"):
        knn_bench.run_parts(["bandai3"], Path("."), 1, 1)


def test_repeat_searcher_answers_as_the_searcher_and_searches_once() -> None:
    rng = np.random.default_rng(0)
    points, clip = rng.normal(size=(200, 4, 3)), np.repeat([0, 1], 100)
    feats, weights, offsets = rng.normal(size=(3, 4, 3)), np.ones((3, 4)), np.array([0, 3, 6])
    allowed = np.ones(200, dtype=bool)
    plain = Searcher(points, clip).windows(feats, weights, offsets, 8, allowed, 5)
    repeat = knn_bench.RepeatSearcher(points, clip)
    for _ in range(2):
        got = repeat.windows(feats, weights, offsets, 8, allowed, 5)
        assert all(np.array_equal(a, b) for a, b in zip(got, plain))
    allowed[:50] = False  # another question: searched anew
    assert not np.isin(repeat.windows(feats, weights, offsets, 8, allowed, 5)[1], np.arange(50)).any()
    assert len(repeat._answers) == 2


def test_every_tuning_grid_starts_with_the_defaults_and_holds_valid_settings() -> None:
    """Every grid is changes of the defaults of its time (a grid may now repeat today's defaults: round H's winner
    is today's defaults); each builds, and the newest round's variants differ from each other as changes of the
    defaults it ran against (round E's: today's without round H's three settings)."""
    for name, grid in knn_bench.GRIDS.items():
        assert grid[0] == {} and variant_name(grid[0]) == "defaults", name
        [WindowSettings(**{**ANGLE_DEFAULTS, **v}) for v in grid]  # bad settings raise ValueError
    round_e = {**ANGLE_DEFAULTS, "pca_pair": False, "fit_twist": None, "pca_gate": None}
    newest = [WindowSettings(**{**round_e, **v}) for v in knn_bench.GRIDS["pair"]]
    assert len(set(newest)) == len(knn_bench.PAIR_VARIANTS)
    assert WindowSettings(**{**round_e, **knn_bench.PAIR_VARIANTS[-1]}) == WindowSettings(**ANGLE_DEFAULTS)
