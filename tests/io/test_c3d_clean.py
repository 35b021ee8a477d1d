"""`mocapnet clean` on C3D files, end to end: what the output keeps, bad output names, truncated inputs,
files only the fallback reader reads."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.cli import main
from mocapnet.io import read_c3d
from mocapnet.io.c3d import load_c3d
from mocapnet.io.c3d_raw import read_layout


def test_clean_gait_to_upper_case_name_keeps_the_lab_file(shared, tmp_path, capsys):
    import ezc3d

    src = shared / "c3d/btkdata/Gait.c3d"
    out = tmp_path / "out.C3D"
    assert main(["clean", str(src), "-o", str(out), "--method", "lerp"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["out.C3D"]
    a, b = ezc3d.c3d(str(src)), ezc3d.c3d(str(out))
    assert b["data"]["points"].shape[1] == 33 and b["data"]["analogs"].shape[1] == 28
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    assert read_layout(out).first_frame == read_layout(src).first_frame and b["header"] == a["header"]
    assert list(b["parameters"]) == list(a["parameters"])
    before, after = load_c3d(src), load_c3d(out)
    measured = before.visible
    np.testing.assert_array_equal(after.xyz[measured], before.xyz[measured])
    np.testing.assert_array_equal(after.residuals[measured], before.residuals[measured])
    filled = after.visible & ~measured
    assert filled.any() and (after.residuals[filled] == 0).all()


@pytest.mark.parametrize("name", ["out", "out.bvh", "", "folder/", "folder.c3d"])
def test_bad_output_names_exit_2_and_write_nothing(shared, tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.c3d").mkdir()
    src = shared / "c3d/btkdata/Gait.c3d"
    assert main(["clean", str(src), "-o", name, "--method", "lerp"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapnet: error: ") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["folder.c3d"]


def test_truncated_input_exit_2_unless_allowed(shared, tmp_path, capsys):
    raw = (shared / "c3d/btkdata/Eb015pi.c3d").read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[: len(raw) // 10])
    out = tmp_path / "out.c3d"
    assert main(["clean", str(cut), "-o", str(out), "--method", "lerp"]) == 2
    assert "450 frames" in capsys.readouterr().err and not out.exists()
    assert main(["clean", str(cut), "-o", str(out), "--method", "lerp", "--allow-truncated"]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if "truncated C3D file" in line]
    assert len(warned) == 1 and "holds 31" in warned[0]
    assert read_c3d(out).n_frames == read_layout(cut).frames_present


def test_clean_a_file_only_the_fallback_reads(shared, tmp_path, capsys):
    src = shared / "c3d/btkdata/sgi_int.c3d"
    out = tmp_path / "sgi_filled.c3d"
    assert main(["clean", str(src), "-o", str(out), "--method", "lerp"]) == 0
    assert "read with c3d" in capsys.readouterr().out  # the message says which reader was used
    before, after = read_c3d(src), read_c3d(out)
    assert after.reader == "c3d" and after.visible.sum() > before.visible.sum()
    np.testing.assert_array_equal(after.points[before.visible], before.points[before.visible])


def test_gaussian_cv_denoises_measured_samples_and_keeps_residuals_and_gaps(tmp_path, capsys):
    """``clean --method gaussian-cv`` on a C3D file: white noise added to every measured sample is mostly
    removed, every residual word stays, the gaps stay missing, and the message says what was smoothed."""
    from mocapnet.io import write_c3d
    from mocapnet.motion import Markers
    from tests.conftest import SAMPLE_C3D_NAN

    truth = read_c3d(SAMPLE_C3D_NAN)
    rng = np.random.default_rng(0)
    noisy_points = truth.points + rng.normal(0, 0.2, truth.points.shape)  # 2 mm
    noisy = tmp_path / "noisy.c3d"
    every = truth.visible.copy()
    write_c3d(noisy, Markers(noisy_points, truth.visible, truth.labels, truth.fps), source=SAMPLE_C3D_NAN,
              filled=np.zeros_like(every), moved=every)  # fmt: skip
    out = tmp_path / "smooth.c3d"
    assert main(["clean", str(noisy), "-o", str(out), "--method", "gaussian-cv"]) == 0
    printed = capsys.readouterr().out
    assert "gaussian-cv smoothed" in printed and "residuals kept" in printed and "left missing" in printed
    before, after = read_c3d(noisy), read_c3d(out)
    np.testing.assert_array_equal(after.visible, truth.visible)
    np.testing.assert_array_equal(load_c3d(out).residuals, load_c3d(noisy).residuals)
    seen = truth.visible
    noise = np.sqrt(((before.points - truth.points)[seen] ** 2).mean())
    left = np.sqrt(((after.points - truth.points)[seen] ** 2).mean())
    assert left < 0.9 * noise  # 2 mm on a 50 fps tennis serve: 0.172 cm left of 0.200 (fixed 0.7-frame Gaussian: 0.158)


@pytest.mark.parametrize("rel", ["btkdata/Gait.c3d", "btkdata/DEC_INT.C3D", "ezc3d/Vicon.c3d"])
def test_gaussian_cv_on_lab_files_keeps_residual_words_and_counts_what_changed(shared, tmp_path, rel):
    """On integer (DEC) and float lab files: only X/Y/Z bytes of measured samples change, every residual word
    (residual and cameras) stays, and the reported count is the samples whose stored position changed."""
    from mocapnet.clean import CleanOptions, clean_file

    src = shared / "c3d" / rel
    out = tmp_path / "smooth.c3d"
    result = clean_file(src, out, CleanOptions(method="gaussian-cv"))
    a, b = load_c3d(src), load_c3d(out)
    np.testing.assert_array_equal(b.residuals, a.residuals)
    layout = read_layout(src)
    raw_a = np.frombuffer(src.read_bytes(), np.uint8)
    raw_b = np.frombuffer(out.read_bytes(), np.uint8)
    changed = np.flatnonzero(raw_a != raw_b)
    word = (changed - layout.data_offset) // layout.word_size
    assert (changed >= layout.data_offset).all() and (word % 4 != 3).all()  # point words only, never the 4th
    before, after = read_c3d(src), read_c3d(out)
    moved = before.visible & (after.points != before.points).any(axis=2)
    assert result.details["smoothed_samples"] == int(moved.sum()) and result.samples_filled == 0
    np.testing.assert_array_equal(after.visible, before.visible)
    assert f"smoothed {int(moved.sum())} measured samples" in result.message
    with pytest.raises(ValueError, match="--plot draws the filled gaps"):
        clean_file(src, tmp_path / "p.c3d", CleanOptions(method="gaussian-cv", plot=str(tmp_path / "p.png")))
    assert not (tmp_path / "p.c3d").exists()
