"""write_c3d(source=...): the output is the source file with only the filled samples replaced."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mocapnet.io import MocapFileError, read_c3d, write_c3d
from mocapnet.io.c3d import TruncatedC3DWarning, load_c3d
from mocapnet.io.c3d_raw import read_layout
from mocapnet.motion import Markers
from tests.conftest import SAMPLE_C3D_NAN


def interpolated(markers: Markers, offset_cm: float = 0.0123) -> Markers:
    """Fill every gap of every marker that has data by linear interpolation (held flat at the ends), moved
    ``offset_cm`` towards 0 so filled values neither fall on an integer file's grid nor leave its range.
    Returns the same class as ``markers`` (a ``C3DMarkers`` keeps its point indices)."""
    pts = markers.points.copy()
    for j in np.flatnonzero(markers.visible.any(axis=0)):
        seen = markers.visible[:, j]
        gap = np.flatnonzero(~seen)
        for k in range(3):
            value = np.interp(gap, np.flatnonzero(seen), pts[seen, j, k])
            pts[gap, j, k] = value - np.sign(value) * offset_cm
    return replace(markers, points=pts, visible=np.isfinite(pts).all(axis=2))


def sample_bytes(src: Path, markers: Markers, filled: np.ndarray) -> set[int]:
    """Byte offsets of the point words (X, Y, Z, residual) of the ``filled`` samples in ``src``."""
    layout = read_layout(src)
    content = load_c3d(src, allow_truncated=True)
    index = {lab: [] for lab in content.labels}
    for i, lab in enumerate(content.labels):
        index[lab].append(i)
    keep = set(content.marker_indices().tolist())
    seen: dict[str, int] = {}
    cols = []
    for lab in markers.labels:
        k = seen.get(lab, 0)
        seen[lab] = k + 1
        cols.append([i for i in index[lab] if i in keep][k])
    ws, stride = layout.word_size, layout.frame_words * layout.word_size
    out = set()
    for t, m in np.argwhere(filled):
        start = layout.data_offset + t * stride + cols[m] * 4 * ws
        out.update(range(start, start + 4 * ws))
    return out


@pytest.mark.parametrize(
    "rel",
    [
        "btkdata/Gait.c3d",  # DEC, int16 (POINT:SCALE 0.074 mm), 33 points of which 29 markers, 28 analogs
        "btkdata/PlugInC3D.c3d",  # DEC int16, 86 points of which 16 markers, EVENT/SEG/SUBJECTS/TRIAL groups
        "ezc3d/Vicon.c3d",  # Intel float, 38 analogs, ANALYSIS/EVENT/EVENT_CONTEXT/SUBJECTS/TRIAL groups
        "btkdata/Dec_real.c3d",  # DEC float (VAX F-floats)
        "btkdata/sgi_int.c3d",  # MIPS int16, read through the PyPI c3d package
        "btkdata/sgi_real.c3d",  # MIPS float, read through the PyPI c3d package
    ],
)
def test_only_filled_samples_change(shared, tmp_path, rel):
    src = shared / "c3d" / rel
    markers = read_c3d(src)
    full = interpolated(markers)
    full = Markers(full.points, full.visible, full.labels, full.fps)  # as a cleaner builds it: labels only
    filled = full.visible & ~markers.visible
    assert filled.any()
    out = tmp_path / "out.C3D"
    write_c3d(out, full, inputs=(src,), source=src)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.C3D"]

    before, after = src.read_bytes(), out.read_bytes()
    assert len(before) == len(after)
    changed = np.flatnonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8))
    assert set(changed.tolist()) <= sample_bytes(src, markers, filled)

    back = read_c3d(out)
    assert back.reader == markers.reader and back.labels == markers.labels and back.fps == markers.fps
    np.testing.assert_array_equal(back.points[markers.visible], markers.points[markers.visible])
    np.testing.assert_array_equal(back.visible, full.visible)
    layout = read_layout(src)
    tolerance = layout.scale / 2 * 0.1 if not layout.is_float else 1e-4  # cm: half the integer step, or float32
    assert np.abs(back.points[filled] - full.points[filled]).max() <= tolerance * 1.0001
    written = load_c3d(out)
    index = [written.labels.index(lab) for lab in markers.labels if markers.labels.count(lab) == 1]
    cols = [markers.labels.index(written.labels[i]) for i in index]
    assert (written.residuals[:, index][filled[:, cols]] == 0).all()  # computed, not measured


def test_gait_to_upper_case_name_keeps_points_analogs_groups_and_first_frame(shared, tmp_path):
    import ezc3d

    src = shared / "c3d/btkdata/Gait.c3d"
    markers = read_c3d(src)
    out = tmp_path / "out.C3D"
    write_c3d(out, interpolated(markers), inputs=(src,), source=src)
    a, b = ezc3d.c3d(str(src)), ezc3d.c3d(str(out))
    assert b["data"]["points"].shape == a["data"]["points"].shape == (4, 33, markers.n_frames)
    assert b["data"]["analogs"].shape[1] == 28
    np.testing.assert_array_equal(b["data"]["analogs"], a["data"]["analogs"])
    assert b["header"] == a["header"]
    assert read_layout(out).first_frame == read_layout(src).first_frame
    assert list(b["parameters"]) == list(a["parameters"])
    for group, params in a["parameters"].items():
        for name, param in params.items():
            if name != "__METADATA__":
                np.testing.assert_array_equal(b["parameters"][group][name]["value"], param["value"])
    res_a, res_b = a["data"]["meta_points"]["residuals"], b["data"]["meta_points"]["residuals"]
    measured = res_a >= 0
    np.testing.assert_array_equal(res_b[measured], res_a[measured])
    np.testing.assert_array_equal(b["data"]["points"][:, measured[0]], a["data"]["points"][:, measured[0]])
    newly = (res_b >= 0) & ~measured
    assert newly.any() and (res_b[newly] == 0).all()  # filled: residual 0, "computed, not measured"
    model = [i for i, lab in enumerate(a["parameters"]["POINT"]["LABELS"]["value"]) if lab not in markers.labels]
    np.testing.assert_array_equal(b["data"]["points"][:, model], a["data"]["points"][:, model])


def test_sample_without_shared_data(tmp_path):
    markers = read_c3d(SAMPLE_C3D_NAN)
    full = interpolated(markers)
    out = tmp_path / "filled.c3d"
    write_c3d(out, full, source=SAMPLE_C3D_NAN)
    back = read_c3d(out)
    assert back.visible.all()
    np.testing.assert_array_equal(back.points[markers.visible], markers.points[markers.visible])
    gap = ~markers.visible
    np.testing.assert_allclose(back.points[gap], full.points[gap], atol=1e-4)


def test_filled_mask_limits_what_is_written(tmp_path):
    markers = read_c3d(SAMPLE_C3D_NAN)
    full = interpolated(markers)
    filled = full.visible & ~markers.visible
    half = filled.copy()
    half[: markers.n_frames // 2] = False
    out = tmp_path / "half.c3d"
    write_c3d(out, full, source=SAMPLE_C3D_NAN, filled=half)
    back = read_c3d(out)
    np.testing.assert_array_equal(back.visible, markers.visible | half)


def test_subset_in_other_order_matched_by_label(tmp_path):
    markers = read_c3d(SAMPLE_C3D_NAN)
    full = interpolated(markers)
    rsho = markers.index("RSHO")
    subset = full.select([rsho, 0])
    out = tmp_path / "subset.c3d"
    write_c3d(out, subset, source=SAMPLE_C3D_NAN)
    back = read_c3d(out)
    assert back.visible[:, rsho].all()
    np.testing.assert_allclose(back.points[:, rsho], full.points[:, rsho], atol=1e-4)


def test_duplicate_labels_go_to_their_own_point(shared, tmp_path):
    src = shared / "c3d/btkdata/Gait.c3d"
    markers = read_c3d(src)
    dup = sorted({lab for lab in markers.labels if markers.labels.count(lab) > 1})
    assert dup
    second = [i for i, lab in enumerate(markers.labels) if lab == dup[0]][1]
    full = interpolated(markers)
    out = tmp_path / "second.c3d"
    write_c3d(out, full.select([second]), source=src)
    back = read_c3d(out)
    first = markers.labels.index(dup[0])
    np.testing.assert_array_equal(back.visible[:, first], markers.visible[:, first])
    assert back.visible[:, second].all()


def test_bad_fills_raise_and_write_nothing(shared, tmp_path):
    markers = read_c3d(SAMPLE_C3D_NAN)
    full = interpolated(markers)
    out = tmp_path / "x.c3d"
    with pytest.raises(ValueError, match="has no value"):
        write_c3d(out, markers, source=SAMPLE_C3D_NAN, filled=~markers.visible)
    with pytest.raises(ValueError, match="bool"):
        write_c3d(out, full, source=SAMPLE_C3D_NAN, filled=np.ones(3, dtype=bool))
    renamed = Markers(full.points, full.visible, ["nope"] + list(full.labels[1:]), full.fps)
    with pytest.raises(MocapFileError, match="'nope'"):
        write_c3d(out, renamed, source=SAMPLE_C3D_NAN)
    with pytest.raises(MocapFileError, match="frames"):
        write_c3d(out, Markers(full.points[:10], full.visible[:10], full.labels, 50.0), source=SAMPLE_C3D_NAN)
    gait = shared / "c3d/btkdata/Gait.c3d"
    g = interpolated(read_c3d(gait))
    far = g.points.copy()
    far[~read_c3d(gait).visible] = 1e6  # 10 km: beyond what the file's int16 words can hold
    with pytest.raises(MocapFileError, match="does not fit this integer C3D file"):
        write_c3d(out, Markers(far, g.visible, g.labels, g.fps), source=gait)
    assert list(tmp_path.iterdir()) == []


def test_truncated_source_gives_a_consistent_file(shared, tmp_path):
    full_file = shared / "c3d/btkdata/Eb015pi.c3d"
    raw = full_file.read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[: len(raw) // 10])
    with pytest.warns(TruncatedC3DWarning, match="450 frames"):
        markers = read_c3d(cut, allow_truncated=True)
    out = tmp_path / "out.c3d"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_c3d(out, interpolated(markers), source=cut)
        back = read_c3d(out)  # no longer truncated: the header says the frames it holds
    assert back.n_frames == markers.n_frames == read_layout(out).frames
    np.testing.assert_array_equal(back.points[markers.visible], markers.points[markers.visible])


@pytest.mark.parametrize("rel", ["btkdata/Gait.c3d", "btkdata/sgi_real.c3d"])
def test_unknown_layout_gives_a_new_file_with_points_and_analogs(shared, tmp_path, monkeypatch, rel):
    """When the data block does not decode to what the reader read, the output is rebuilt through ezc3d."""
    import mocapnet.io.c3d as c3d_module

    src = shared / "c3d" / rel
    markers = read_c3d(src)
    full = interpolated(markers)
    filled = full.visible & ~markers.visible
    real = c3d_module.decode_points
    monkeypatch.setattr(c3d_module, "decode_points", lambda layout, raw: (real(layout, raw)[0] + 1.0, None))
    out = tmp_path / "rebuilt.c3d"
    with pytest.warns(c3d_module.C3DRebuiltWarning, match="cannot edit this file in place"):
        write_c3d(out, full, source=src)
    before, after = load_c3d(src), load_c3d(out)
    assert after.reader == "ezc3d" and after.labels == before.labels and after.rate == pytest.approx(before.rate)
    assert after.units == before.units
    np.testing.assert_allclose(after.analogs, before.analogs, rtol=1e-6, atol=1e-6)
    measured = before.visible
    np.testing.assert_allclose(after.xyz[measured], before.xyz[measured], rtol=1e-6, atol=1e-4)
    back = read_c3d(out)
    np.testing.assert_array_equal(back.visible, full.visible)
    np.testing.assert_allclose(back.points[filled], full.points[filled], atol=1e-4)
    unique = [m for m, lab in enumerate(markers.labels) if after.labels.count(lab) == 1]
    cols = [after.labels.index(markers.labels[m]) for m in unique]
    assert (after.residuals[:, cols][filled[:, unique]] == 0).all()


@pytest.mark.parametrize("rel", ["btkdata/Gait.c3d", "ezc3d/Vicon.c3d", "btkdata/sgi_real.c3d"])
def test_moved_samples_get_new_positions_and_keep_their_residual_words(shared, tmp_path, rel):
    """``moved=``: measured samples rewritten (a smoother's output) keep residual and cameras; only their X, Y, Z
    words change; a moved sample that is not measured, or also filled, is refused and nothing is written."""
    src = shared / "c3d" / rel
    markers = read_c3d(src)
    moved = markers.visible.copy()
    moved[::2] = False  # every other frame
    # 3.7 mm toward 0 (off an integer file's grid, never out of its range)
    shifted = markers.points - np.where(moved[..., None], 0.37 * np.sign(markers.points), 0.0)
    new = Markers(shifted, markers.visible, markers.labels, markers.fps)
    out = tmp_path / "moved.c3d"
    write_c3d(out, new, inputs=(src,), source=src, filled=np.zeros_like(moved), moved=moved)
    before, after = src.read_bytes(), out.read_bytes()
    changed = set(np.flatnonzero(np.frombuffer(before, np.uint8) != np.frombuffer(after, np.uint8)).tolist())
    layout = read_layout(src)
    residual_bytes = {
        b
        for b in sample_bytes(src, markers, moved)
        if (b - layout.data_offset) % (4 * layout.word_size) >= 3 * layout.word_size
    }
    assert changed and changed <= sample_bytes(src, markers, moved) and not changed & residual_bytes
    a, b = load_c3d(src), load_c3d(out)
    np.testing.assert_array_equal(b.residuals, a.residuals)
    back = read_c3d(out)
    tolerance = layout.scale / 2 * 0.1 if not layout.is_float else 1e-4
    assert np.abs(back.points[moved] - shifted[moved]).max() <= tolerance * 1.0001
    np.testing.assert_array_equal(back.points[markers.visible & ~moved], markers.points[markers.visible & ~moved])
    gap = np.argwhere(~markers.visible)
    if len(gap):
        wrong = moved.copy()
        wrong[tuple(gap[0])] = True
        with pytest.raises(ValueError, match="moved sample at frame"):
            write_c3d(tmp_path / "bad.c3d", new, source=src, filled=np.zeros_like(moved), moved=wrong)
    with pytest.raises(ValueError, match="moved sample"):
        write_c3d(tmp_path / "bad.c3d", new, source=src, filled=moved, moved=moved)
    assert not (tmp_path / "bad.c3d").exists()
