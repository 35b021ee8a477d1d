"""Tests of the kNN benchmark's bookkeeping (mocapnet.evaluate.knn_bench): the selection rule and the verdicts."""

from __future__ import annotations

from mocapnet.evaluate import knn_bench
from mocapnet.evaluate.knn_bench import TUNE_CORRUPTIONS, TUNE_VARIANTS, evenly, tune_scores, variant_name, verdicts


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
