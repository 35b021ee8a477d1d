import csv

import numpy as np
import pytest

from mocapnet.cli import main
from mocapnet.evaluate.harness import evaluate
from mocapnet.evaluate.report import plot_per_motion, summarize, table
from mocapnet.io import read_bvh, read_c3d
from tests.conftest import SAMPLE_BVH, SAMPLE_C3D_NAN


def test_evaluate_sample_is_reproducible():
    a = evaluate("sample", "angular-0.5", ["gaussian-58ms"], repeats=2, progress=False)
    b = evaluate("sample", "angular-0.5", ["gaussian-58ms"], repeats=2, progress=False)
    assert [r["angle_err_deg"] for r in a.rows] == [r["angle_err_deg"] for r in b.rows]
    summary = {e["method"]: e for e in summarize(a)}
    assert set(summary) == {"gaussian-58ms", "noisy", "gaussian-125ms", "gaussian-tuned"}  # references added
    assert min(summary[g]["ratio"] for g in ("gaussian-58ms", "gaussian-125ms", "gaussian-tuned")) == 1.0
    assert summary["noisy"]["angle_err_deg"] > 2 * summary["gaussian-58ms"]["angle_err_deg"]


def test_gap_evaluation_uses_the_better_interpolation(tmp_path):
    ev = evaluate("sample", "gaps", ["gaussian-58ms"], repeats=1, progress=False)
    summary = {e["method"]: e for e in summarize(ev)}
    assert min(summary["lerp"]["ratio"], summary["spline"]["ratio"]) == 1.0
    assert np.isfinite(summary["gaussian-58ms"]["gap_err_deg"])
    assert "gap err" in table(ev) and "| lerp |" in table(ev, markdown=True)
    plot_per_motion(ev, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_c3d_folder_evaluation(tmp_path):
    folder = tmp_path / "c3d"
    folder.mkdir()
    (folder / "a.c3d").write_bytes(SAMPLE_C3D_NAN.read_bytes())
    ev = evaluate(str(folder), "segment-gap:right-arm:1", ["spline"], repeats=2, progress=False)
    assert ev.space == "points"
    summary = {e["method"]: e for e in summarize(ev)}
    assert 0 < summary["spline"]["point_err_cm"] < summary["lerp"]["point_err_cm"]
    with pytest.raises(ValueError, match="works on angles"):
        evaluate(str(folder), "segment-gap:right-arm:1", ["gaussian-58ms"], repeats=1, progress=False)


def test_cli_evaluate_scores_every_corruption_given(tmp_path, capsys):
    """--corruption is repeatable: one table per corruption (none was silently dropped), all rows in one CSV,
    one markdown section and one plot each."""
    args = ["evaluate", "--data", "sample", "--method", "gaussian-58ms+check", "--repeats", "1", "--quiet"]
    args += ["--corruption", "none", "--corruption", "angular-0.5", "--corruption", "none"]
    args += ["--csv", str(tmp_path / "s.csv"), "--markdown", str(tmp_path / "s.md"), "--plot", str(tmp_path / "p.png")]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert printed.count("sample: none,") == 1 and printed.count("sample: angular-0.5,") == 1
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert {r["corruption"] for r in rows} == {"none", "angular-0.5"}
    assert {r["method"] for r in rows if r["corruption"] == "none"} >= {"gaussian-58ms+check", "noisy"}
    markdown = (tmp_path / "s.md").read_text()
    assert markdown.count("## sample: ") == 2 and markdown.count("| gaussian-58ms+check |") == 2
    assert (tmp_path / "p_none.png").stat().st_size > 0 and (tmp_path / "p_angular-0.5.png").stat().st_size > 0


def test_cli_evaluate_with_a_bad_corruption_among_several_scores_and_writes_nothing(tmp_path, capsys):
    args = ["evaluate", "--data", "sample", "--method", "gaussian-58ms", "--repeats", "1", "--quiet"]
    args += ["--corruption", "none", "--corruption", "bogus-9", "--plot", str(tmp_path / "p.png")]
    args += ["--csv", str(tmp_path / "s.csv"), "--markdown", str(tmp_path / "s.md")]
    assert main(args) == 2
    captured = capsys.readouterr()
    assert "unknown corruption 'bogus-9'" in captured.err and "sample: none" not in captured.out
    assert list(tmp_path.iterdir()) == []


def test_cli_evaluate_writes_csv(tmp_path, capsys):
    out = tmp_path / "s.csv"
    rc = main(
        [
            "evaluate",
            "--data",
            "sample",
            "--corruption",
            "angular-0.5",
            "--method",
            "gaussian-58ms",
            "--repeats",
            "1",
            "--csv",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "gaussian-58ms" in printed and "ratio" in printed
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 4  # gaussian-58ms and the references noisy, gaussian-125ms, gaussian-tuned
    assert (
        list(rows[0])[:7]
        == ["method", "corruption", "file", "repeat", "angle_err_deg", "gap_err_deg", "pos_err_cm"][:4]
        + list(rows[0])[4:7]
    )
    assert {"angle_err_deg", "gap_err_deg", "pos_err_cm"} <= set(rows[0])


def test_cli_clean_c3d_and_bvh(tmp_path, capsys):
    out = tmp_path / "filled.c3d"
    assert main(["clean", str(SAMPLE_C3D_NAN), "-o", str(out), "--method", "spline"]) == 0
    assert read_c3d(out).visible.all()
    bvh_out = tmp_path / "smooth.bvh"
    assert main(["clean", str(SAMPLE_BVH), "-o", str(bvh_out), "--method", "gaussian-58ms"]) == 0
    assert read_bvh(bvh_out).n_frames == 2752


def test_cli_errors_exit_2_and_write_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text(
        "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1\nx\n"
    )
    out = tmp_path / "out.bvh"
    assert main(["clean", str(bad), "-o", str(out), "--method", "lerp"]) == 2
    err = capsys.readouterr().err
    assert "bad.bvh:11" in err and "'x' is not a number" in err
    assert not out.exists()
    assert main(["clean", str(SAMPLE_C3D_NAN), "-o", str(SAMPLE_C3D_NAN), "--method", "lerp"]) == 2
    assert "same as the input" in capsys.readouterr().err
    assert main(["evaluate", "--data", "sample", "--corruption", "bogus", "--quiet"]) == 2
    assert "unknown corruption" in capsys.readouterr().err
    assert main(["evaluate", "--data", "sample", "--method", "nope", "--quiet"]) == 2


def test_help_has_examples(capsys):
    for verb in ("evaluate", "clean"):
        with pytest.raises(SystemExit):
            main([verb, "--help"])
        assert "examples:" in capsys.readouterr().out


def test_style_filter(shared):
    ev = evaluate("bandai1", "angular-0.5", ["gaussian-58ms"], repeats=1, progress=False, style="normal")
    files = {r["file"] for r in ev.rows}
    assert files and all("_normal_" in f for f in files)
    with pytest.raises(ValueError, match="no clip of style 'nope'"):
        evaluate("bandai1", "angular-0.5", ["gaussian-58ms"], repeats=1, progress=False, style="nope")


def test_clean_of_a_skeleton_without_shipped_model(tmp_path, capsys):
    """The default (auto) cleans it with gaussian-cv and says so; --method ebf refuses it by name."""
    from mocapnet.io import write_bvh
    from mocapnet.motion import Motion, Skeleton

    rot = ("Zrotation", "Xrotation", "Yrotation")
    sk = Skeleton(
        ("Hips", "Leg"),
        (-1, 0),
        np.array([[0, 0, 0], [0, -40.0, 0]]),
        (("Xposition", "Yposition", "Zposition", *rot), rot),
    )
    write_bvh(tmp_path / "tiny.bvh", Motion(sk, np.zeros((10, 9)), 30.0))
    assert main(["clean", str(tmp_path / "tiny.bvh"), "-o", str(tmp_path / "out.bvh"), "--quiet"]) == 0
    assert "gaussian-cv" in capsys.readouterr().out and (tmp_path / "out.bvh").exists()
    args = ["clean", str(tmp_path / "tiny.bvh"), "-o", str(tmp_path / "out2.bvh"), "--method", "ebf"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "no shipped 'ebf' checkpoint for this skeleton, 2 joints" in err and "bandai2: 22 joints" in err
    assert not (tmp_path / "out2.bvh").exists()


def test_parallel_evaluate_scores_equal_serial(tmp_path):
    """Clips scored on two local Dask workers give the rows of the in-process run (all but the timings)."""
    from mocapnet.io import write_bvh
    from mocapnet.parallel import Parallel

    motion = read_bvh(SAMPLE_BVH)
    for i in range(10):
        write_bvh(tmp_path / f"clip_{i:02d}.bvh", motion.with_channels(motion.channels[180 * i : 180 * i + 240]))
    methods = ["gaussian-58ms", "lerp"]
    serial = evaluate(str(tmp_path), "noise+gaps", methods, repeats=2, progress=False)
    spread = evaluate(str(tmp_path), "noise+gaps", methods, repeats=2, progress=False, parallel=Parallel(workers=2))
    drop = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert len(serial.rows) == 10 * 2 * len(serial.methods)
    np.testing.assert_equal(drop(spread.rows), drop(serial.rows))  # NaN (no point error) equals NaN


def test_pose_errors_convert_once_and_match_the_separate_errors(cmu_short):
    from mocapnet.evaluate import metrics

    rng = np.random.default_rng(0)
    sk = cmu_short.skeleton
    noisy = cmu_short.channels + rng.normal(0, 2, cmu_short.channels.shape) * sk.scored_mask
    rot, pos = metrics.pose_errors(cmu_short, noisy)
    assert rot == metrics.rot_err_deg(cmu_short, noisy) and pos == metrics.pos_err_cm(cmu_short, noisy)
    assert 0 < rot < 5 and pos > 0
    gap = noisy.copy()
    gap[5, np.flatnonzero(sk.scored_mask)[0]] = np.nan
    assert all(np.isnan(metrics.pose_errors(cmu_short, gap)))


def test_headline_reference_is_the_best_of_the_three_gaussians():
    """One rule: for noise the ratio divides by the best of gaussian-58ms, gaussian-125ms and gaussian-tuned,
    whichever it is; every table carries all three."""
    from mocapnet.evaluate.harness import GAUSSIANS, Evaluation, reference, reference_methods
    from mocapnet.evaluate.report import headline

    for corruption in ("angular-0.5", "spatial-0.5cm", "bias-sine", "uniform-0.5"):
        assert reference(corruption, "angles").methods == GAUSSIANS
        assert set(GAUSSIANS) <= set(reference_methods(corruption, "angles"))
    for best in GAUSSIANS:
        rows = [
            {"method": m, "angle_err_deg": 1.0 if m == best else 2.0 + i, "gap_err_deg": float("nan"),
             "rot_err_deg": 1.0, "pos_err_cm": 1.0, "point_err_cm": float("nan"), "frames": 10, "seconds": 0.1}
            for i, m in enumerate(("noisy", *GAUSSIANS, "mine"))
        ]  # fmt: skip
        ev = Evaluation("x", "angular-0.5", "angles", ["mine", "noisy", *GAUSSIANS], rows)
        assert headline(ev) == ("angle_err_deg", GAUSSIANS)
        ratios = {e["method"]: e["ratio"] for e in summarize(ev)}
        assert ratios[best] == 1.0 and ratios["mine"] == (2.0 + 4) / 1.0
        assert f"best of {', '.join(GAUSSIANS)}" in table(ev)
    assert headline(Evaluation("x", "noise+gaps", "angles", [])) == ("gap_err_deg", ("lerp+gaussian-58ms",))
    assert headline(Evaluation("x", "gaps", "angles", [])) == ("gap_err_deg", ("lerp", "spline"))
    assert headline(Evaluation("x", "segment-gap:arms:1", "points", [])) == ("point_err_cm", ("lerp", "spline"))


def test_write_csv_gzip_is_reproducible(tmp_path):
    import gzip

    from mocapnet.evaluate.report import write_csv

    ev = evaluate("sample", "gaps", ["lerp"], repeats=1, progress=False)
    write_csv(tmp_path / "a.csv", ev.rows)
    write_csv(tmp_path / "a.csv.gz", ev.rows)
    write_csv(tmp_path / "b.csv.gz", ev.rows)
    assert gzip.decompress((tmp_path / "a.csv.gz").read_bytes()) == (tmp_path / "a.csv").read_bytes()
    assert (tmp_path / "a.csv.gz").read_bytes() == (tmp_path / "b.csv.gz").read_bytes()


def test_test_only_corpus_tunes_its_gaussian_reference_elsewhere():
    from mocapnet.evaluate.harness import Evaluation, corpus_references

    assert "gaussian-tuned:tune_on=bandai2" in corpus_references("bandai1", "angular-0.5")
    assert "gaussian-tuned" in corpus_references("bandai2", "angular-0.5")
    assert corpus_references("bandai1", "gaps") == ["lerp", "spline"]
    rows = [
        {"method": m, "angle_err_deg": v, "gap_err_deg": float("nan"), "rot_err_deg": 1.0, "pos_err_cm": 1.0,
         "point_err_cm": float("nan"), "frames": 10, "seconds": 0.1}
        for m, v in (("gaussian-58ms", 2.0), ("gaussian-tuned:tune_on=bandai2", 1.5), ("mine", 1.2))
    ]  # fmt: skip
    ev = Evaluation("bandai1", "angular-0.5", "angles", [r["method"] for r in rows], rows)
    ratios = {e["method"]: e["ratio"] for e in summarize(ev)}
    assert ratios["gaussian-tuned:tune_on=bandai2"] == 1.0 and ratios["mine"] == 1.2 / 1.5


@pytest.mark.parametrize("bad", [["--limit", "0"], ["--repeats", "-2"], ["--threads", "0"], ["--limit", "x"]])
def test_cli_counts_below_one_are_refused_by_name(bad, capsys):
    """A count of clips, repeats or threads below 1 is a usage error naming the option (was: an empty table, or
    "list index out of range")."""
    with pytest.raises(SystemExit) as stop:
        main(["evaluate", "--data", "sample", "--corruption", "gaps", "--method", "lerp", "--quiet", *bad])
    assert stop.value.code == 2
    assert f"argument {bad[0]}: a whole number >= 1" in capsys.readouterr().err


@pytest.mark.parametrize("bad", [{"repeats": 0}, {"limit": 0}, {"repeats": 1.5}])
def test_evaluate_refuses_counts_below_one(bad):
    with pytest.raises(ValueError, match=f"{next(iter(bad))} must be a whole number >= 1"):
        evaluate("sample", "gaps", ["lerp"], **{"repeats": 1, **bad}, progress=False)
