import time

import numpy as np
import pytest

from mocapnet.io import MocapFileError, read_c3d, write_c3d
from mocapnet.io.c3d import READERS, TruncatedC3DWarning
from mocapnet.io.c3d_raw import read_layout
from tests.conftest import SAMPLE_C3D, SAMPLE_C3D_NAN


def test_read_sample_in_cm():
    m = read_c3d(SAMPLE_C3D)
    assert m.points.shape == (1092, 39, 3)
    assert m.fps == 50.0
    assert m.visible.all()
    assert m.labels[0] == "Derrick:C7"
    # file is in metres: a person's markers span about 1-2 m vertically
    assert 100 < np.ptp(m.points[0, :, 2]) < 250


def test_missing_samples_are_nan_and_invisible():
    m = read_c3d(SAMPLE_C3D_NAN)
    rsho = m.index("RSHO")
    assert (~m.visible).sum() == (~m.visible[:, rsho]).sum() == 145
    assert np.isnan(m.points[~m.visible]).all()


def test_round_trip(tmp_path):
    m = read_c3d(SAMPLE_C3D_NAN)
    write_c3d(tmp_path / "x.c3d", m)
    back = read_c3d(tmp_path / "x.c3d")
    assert back.labels == m.labels and back.fps == m.fps
    np.testing.assert_array_equal(back.visible, m.visible)
    np.testing.assert_allclose(back.points[m.visible], m.points[m.visible], atol=1e-3)


def test_refuses_to_overwrite_input(tmp_path):
    m = read_c3d(SAMPLE_C3D)
    src = tmp_path / "in.c3d"
    src.write_bytes(SAMPLE_C3D.read_bytes())
    with pytest.raises(MocapFileError, match="same as the input"):
        write_c3d(src, m, inputs=(src,))
    assert src.read_bytes() == SAMPLE_C3D.read_bytes()


@pytest.mark.parametrize(
    "name, message",
    [
        ("Empty.c3d", "file is empty"),
        ("MACsample.c3d", "MIPS processor type not supported"),
        ("MACsample.c3d", "nor can the c3d package: inconsistent scale factor"),
        ("bad_parameter_section.c3d", "parameter section is damaged"),
        ("badParameterOffset.c3d", "parameter section is damaged (POINT:LABELS runs into the next entry)"),
        ("mocap36.c3d", "parameter section is damaged (POINT:LABELS runs into the next entry)"),
        ("phasespace_sample.c3d", "no POINT data"),
        ("parameterOverflow.c3d", "every marker sample is missing"),
    ],
)
def test_broken_files_give_clear_errors(shared, name, message):
    path = shared / "c3d/btkdata" / name
    with pytest.raises(MocapFileError) as err:
        read_c3d(path)
    assert str(path) in str(err.value) and message in str(err.value)
    assert "\n" not in str(err.value)


def test_damaged_parameter_section_refused_in_under_a_second(shared):
    path = shared / "c3d/btkdata/bad_parameter_section.c3d"
    start = time.perf_counter()
    with pytest.raises(MocapFileError, match="parameter section is damaged"):
        read_c3d(path)
    assert time.perf_counter() - start < 1.0


@pytest.mark.parametrize(
    "name, frames, points, rate",
    [
        ("sgi_int.c3d", 89, 36, 50.0),  # MIPS (SGI) int16
        ("sgi_real.c3d", 89, 36, 50.0),  # MIPS float
        ("c3d.org__sample13__Dance.c3d", 499, 40, 65.05),  # PhoeniX: ANALOG:OFFSET stored as float
        ("golfswing.c3d", 514, 29, 107.53),
    ],
)
def test_files_ezc3d_refuses_load_through_the_c3d_package(shared, name, frames, points, rate):
    m = read_c3d(shared / "c3d/btkdata" / name)
    assert m.reader == "c3d"
    assert m.points.shape == (frames, points, 3) and m.fps == pytest.approx(rate, abs=0.01)
    assert m.visible.any() and not np.isnan(m.points[m.visible]).any()


def test_mips_file_reads_as_its_intel_twin(shared):
    """sgi_int.c3d and pc_int.c3d hold the same recording (c3d.org sample02) for two processors."""
    mips, intel = read_c3d(shared / "c3d/btkdata/sgi_int.c3d"), read_c3d(shared / "c3d/btkdata/pc_int.c3d")
    assert (mips.reader, intel.reader) == ("c3d", "ezc3d") and mips.labels == intel.labels
    np.testing.assert_array_equal(mips.visible, intel.visible)
    np.testing.assert_allclose(mips.points[mips.visible], intel.points[intel.visible], atol=1e-4)


def test_truncated_file_names_both_frame_counts(shared, tmp_path):
    raw = (shared / "c3d/btkdata/Eb015pi.c3d").read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(raw[: len(raw) // 10])  # 450 frames in the header, 31 complete in the data block
    with pytest.raises(MocapFileError, match=r"cut.c3d: truncated C3D file: the header says 450 frames .* holds 31"):
        read_c3d(cut)
    with pytest.warns(TruncatedC3DWarning, match="holds 31"):
        m = read_c3d(cut, allow_truncated=True)
    whole = read_c3d(shared / "c3d/btkdata/Eb015pi.c3d")
    assert m.n_frames == 31
    np.testing.assert_array_equal(m.points[m.visible], whole.points[:31][m.visible])
    header_only = tmp_path / "header.c3d"
    header_only.write_bytes(raw[: read_layout(cut).data_offset])
    with pytest.raises(MocapFileError, match="holds 0"):
        read_c3d(header_only, allow_truncated=True)


def test_header_and_point_used_disagreeing_is_named_not_called_truncated(shared, tmp_path):
    """A file whose data block fits the header's point count but not ``POINT:USED`` (which ezc3d and the ``c3d``
    package read by) is refused naming both counts, with or without ``--allow-truncated``: read by POINT:USED its
    data would be garbage, and it is not truncated."""
    src = shared / "c3d/btkdata/Eb015pi.c3d"
    raw = bytearray(src.read_bytes())
    layout = read_layout(src)
    used = layout.parameters[("POINT", "USED")]
    assert used.type == 2 and int(np.frombuffer(used.data[:2], "<i2")[0]) == layout.n_points
    raw[used.offset : used.offset + 2] = np.array([layout.n_points + 1], "<i2").tobytes()
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(bytes(raw))
    for used_points in (layout.n_points + 1, layout.n_points - 1):  # too short for POINT:USED, or too long
        raw[used.offset : used.offset + 2] = np.array([used_points], "<i2").tobytes()
        bad.write_bytes(bytes(raw))
        wanted = rf"header says {layout.n_points} points per frame and POINT:USED says {used_points}"
        for allow in (False, True):
            with pytest.raises(MocapFileError, match=wanted):
                read_c3d(bad, allow_truncated=allow)


def test_not_a_c3d(tmp_path):
    path = tmp_path / "x.c3d"
    path.write_bytes(b"HIERARCHY\n" * 100)
    with pytest.raises(MocapFileError, match="not a C3D file"):
        read_c3d(path)


def test_every_shared_c3d_loads_or_fails_clearly(shared):
    files = sorted((shared / "c3d").rglob("*.[cC]3[dD]"))
    assert len(files) == 51
    loaded, failed = {}, {}
    for f in files:
        start = time.perf_counter()
        try:
            m = read_c3d(f)
        except MocapFileError as exc:
            failed[f.name] = time.perf_counter() - start
            assert str(f) in str(exc) and "\n" not in str(exc)
            continue
        loaded[f.name] = m.reader
        assert m.points.shape[:2] == m.visible.shape and m.fps > 0
        assert not np.isnan(m.points[m.visible]).any()
    assert set(loaded.values()) == set(READERS)
    fallback = {"sgi_int.c3d", "sgi_real.c3d", "c3d.org__sample13__Dance.c3d", "golfswing.c3d"}
    assert {name for name, reader in loaded.items() if reader == "c3d"} == fallback
    assert max(failed.values()) < 15.0, failed
    assert len(loaded) > 4 * len(failed)
    physical = read_c3d(shared / "c3d/pycgm/Movement_trial.c3d")
    assert physical.n_markers == 39  # 200 model outputs and PiG virtual points left out
