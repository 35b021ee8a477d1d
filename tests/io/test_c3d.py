import numpy as np
import pytest

from mocapnet.io import MocapFileError, read_c3d, write_c3d
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
        ("c3d.org__sample13__Dance.c3d", "ezc3d cannot read this C3D file: OFFSET parameter is not an INT"),
        ("Empty.c3d", "file is empty"),
        ("MACsample.c3d", "MIPS processor type not supported"),
        ("sgi_real.c3d", "MIPS processor type not supported"),
        ("bad_parameter_section.c3d", "ezc3d cannot read this C3D file"),
        ("badParameterOffset.c3d", "ezc3d cannot read this C3D file"),
        ("mocap36.c3d", "ezc3d cannot read this C3D file"),
        ("phasespace_sample.c3d", "no POINT data"),
        ("parameterOverflow.c3d", "every marker sample is missing"),
    ],
)
def test_broken_files_give_clear_errors(shared, name, message):
    path = shared / "c3d/btkdata" / name
    with pytest.raises(MocapFileError) as err:
        read_c3d(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_not_a_c3d(tmp_path):
    path = tmp_path / "x.c3d"
    path.write_bytes(b"HIERARCHY\n" * 100)
    with pytest.raises(MocapFileError, match="not a C3D file"):
        read_c3d(path)


def test_every_shared_c3d_loads_or_fails_clearly(shared):
    files = sorted((shared / "c3d").rglob("*.[cC]3[dD]"))
    assert len(files) == 51
    ok = 0
    for f in files:
        try:
            m = read_c3d(f)
        except MocapFileError as exc:
            assert str(f) in str(exc)
            continue
        ok += 1
        assert m.points.shape[:2] == m.visible.shape and m.fps > 0
        assert not np.isnan(m.points[m.visible]).any()
    assert ok >= 40
    physical = read_c3d(shared / "c3d/pycgm/Movement_trial.c3d")
    assert physical.n_markers == 39  # 200 model outputs and PiG virtual points left out
