import gzip

import numpy as np
import pytest

from mocapnet.io import MocapFileError, read_bvh, write_bvh
from mocapnet.io.bvh import format_bvh, parse_bvh

GOOD = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT Leg
\t{
\t\tOFFSET 0 -10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -10 0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 90 0 0 0 0 10 20 30
0 91 0 0 0 0 11 21 31
0 92 0 0 0 0 12 22 179
"""


def test_parse_minimal_hierarchy():
    m = parse_bvh(GOOD, "good.bvh", cm_per_unit=1.0)
    assert m.skeleton.names == ("Hips", "Leg")
    assert m.skeleton.parents == (-1, 0)
    assert m.channels.shape == (3, 9)
    assert m.fps == 30.0
    assert m.skeleton.scored_mask.tolist() == [False] * 6 + [True] * 3


def test_unwrap_along_time():
    text = GOOD.replace("12 22 179", "12 22 -179").replace("11 21 31", "11 21 178")
    m = parse_bvh(text, "wrap.bvh", cm_per_unit=1.0)
    assert m.channels[2, 8] == pytest.approx(181.0)
    assert parse_bvh(text, "wrap.bvh", unwrap=False).channels[2, 8] == pytest.approx(-179.0)


def test_length_units(cmu, bandai):
    assert cmu.skeleton.cm_per_unit == pytest.approx(2.54 / 0.45)
    assert bandai.skeleton.cm_per_unit == 1.0
    assert cmu.fps == 120.0 and bandai.fps == 30.0


def test_round_trip_exact(tmp_path, cmu, bandai):
    for motion in (cmu, bandai):
        for name in ("out.bvh", "out.bvh.gz"):
            path = tmp_path / name
            write_bvh(path, motion)
            back = read_bvh(path)
            assert back.skeleton.topology() == motion.skeleton.topology()
            np.testing.assert_allclose(back.skeleton.offsets, motion.skeleton.offsets, atol=1e-4)
            np.testing.assert_allclose(back.channels, motion.channels, atol=1e-4)
            assert back.fps == motion.fps


def test_written_file_reads_in_reference_package(tmp_path, bandai):
    """The PyPI ``bvh`` package (the reference) imports our output with the same hierarchy and values."""
    from bvh import Bvh

    write_bvh(tmp_path / "b.bvh", bandai)
    ref = Bvh((tmp_path / "b.bvh").read_text())
    assert ref.get_joints_names() == list(bandai.skeleton.names)
    assert ref.nframes == bandai.n_frames
    np.testing.assert_allclose(np.array(ref.frames, dtype=float), bandai.channels, atol=1e-4)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t[: t.index("0 92")], "Frames: 3' but the MOTION section has 2"),
        (lambda t: t.replace("0 91 0 0 0 0 11 21 31", "0 91 0 0 0 0 11 21"), ":20: expected 9 values per frame, got 8"),
        (lambda t: t.replace("11 21 31", "11 abc 31"), ":20: 'abc' is not a number"),
        (lambda t: t.replace("11 21 31", "11 nan 31"), ":20: frame 2 channel Leg.Xrotation is nan"),
        (lambda t: t.replace("11 21 31", "11 inf 31"), ":20: frame 2 channel Leg.Xrotation is inf"),
        (lambda t: t.replace("Frames: 3", "Frames: 5"), "'Frames: 5' but the MOTION section has 3"),
        (lambda t: t.replace("Zrotation Xrotation Yrotation", "Zrotation Xrot Yrotation"), ":9: unknown channel"),
        (lambda t: t[: t.index("Frames")], "file ends before 'Frames:'"),
        (lambda t: t[: t.index("0 90")], "empty MOTION section"),
        (lambda t: t.replace("Frames: 3", "Frames: 0")[: t.index("0 90")], "empty MOTION section"),
        (lambda t: t[: t.index("MOTION")], "file ends before the MOTION section"),
        (lambda t: t.replace("HIERARCHY", "HIERARCHX"), ":1: expected 'HIERARCHY'"),
        (lambda t: t.replace("OFFSET 0 -10 0", "OFFSET 0 x 0", 1), ":8: OFFSET values are not numbers"),
        (lambda t: t.replace("CHANNELS 3", "CHANNELS 4"), ":9: CHANNELS says 4 but lists 3"),
    ],
    ids=[
        "truncated",
        "wrong-count",
        "non-numeric",
        "nan",
        "inf",
        "frames-mismatch",
        "unknown-channel",
        "no-frames-line",
        "empty-motion",
        "zero-frames",
        "truncated-hierarchy",
        "not-bvh",
        "bad-offset",
        "channel-count",
    ],
)
def test_bad_input_names_file_and_line(tmp_path, edit, message):
    path = tmp_path / "bad.bvh"
    path.write_text(edit(GOOD))
    with pytest.raises(MocapFileError) as err:
        read_bvh(path)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_truncated_gzip(tmp_path):
    data = gzip.compress(GOOD.encode())
    path = tmp_path / "cut.bvh.gz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(MocapFileError, match="cut.bvh.gz"):
        read_bvh(path)


def test_nothing_written_on_failure_and_no_overwrite(tmp_path, cmu_short):
    src = tmp_path / "in.bvh"
    write_bvh(src, cmu_short)
    before = src.read_bytes()
    with pytest.raises(MocapFileError, match="same as the input"):
        write_bvh(src, cmu_short, inputs=(src,))
    assert src.read_bytes() == before
    bad = cmu_short.with_channels(
        np.where(np.arange(cmu_short.channels.size).reshape(cmu_short.channels.shape) == 5, np.nan, cmu_short.channels)
    )
    with pytest.raises(MocapFileError, match="frame 1"):
        write_bvh(tmp_path / "out.bvh", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.bvh"]


def test_format_has_standard_syntax(cmu_short):
    text = format_bvh(cmu_short)
    assert text.startswith("HIERARCHY\nROOT Hips\n{")
    assert "\nMOTION\nFrames: 600\nFrame Time: 0.008333333" in text
    assert text.count("{") == text.count("}")


def test_every_shared_bvh_loads_and_round_trips(shared, tmp_path):
    """Every BVH file under the shared data loads; every one round-trips to 1e-4 (text in memory)."""
    files = sorted((shared / "bvh").rglob("*.bvh*"))
    assert len(files) > 3000
    for f in files:
        m = read_bvh(f)
        back = parse_bvh(format_bvh(m), f, cm_per_unit=m.skeleton.cm_per_unit)
        assert np.abs(back.channels - m.channels).max() < 1e-4, f
        assert np.abs(back.skeleton.offsets - m.skeleton.offsets).max() < 1e-4, f


def test_large_rig_with_mixed_channel_orders(tmp_path):
    """A 100-joint rig (iClone-sized) with every Euler order and 3- or 6-channel joints round-trips."""
    from mocapnet.motion import Motion, Skeleton

    rng = np.random.default_rng(0)
    orders = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]
    n = 100
    parents = tuple([-1] + [int(rng.integers(0, j)) for j in range(1, n)])
    channels = tuple(
        (("Xposition", "Yposition", "Zposition") if j % 7 == 0 else ()) + tuple(f"{a}rotation" for a in orders[j % 6])
        for j in range(n)
    )
    sk = Skeleton(tuple(f"joint{j}" for j in range(n)), parents, rng.normal(size=(n, 3)), channels)
    motion = Motion(sk, rng.uniform(-170, 170, (20, sk.n_channels)), 60.0, "rig")
    write_bvh(tmp_path / "rig.bvh", motion)
    back = read_bvh(tmp_path / "rig.bvh", unwrap=False)
    # the file is in depth-first order: compare joint by joint
    assert back.skeleton.n_joints == n and set(back.skeleton.names) == set(sk.names)
    for j, name in enumerate(sk.names):
        k = back.skeleton.names.index(name)
        assert back.skeleton.channels[k] == sk.channels[j]
        p = back.skeleton.parents[k]
        assert (p < 0 and sk.parents[j] < 0) or back.skeleton.names[p] == sk.names[sk.parents[j]]
        np.testing.assert_allclose(
            back.channels[:, back.skeleton.joint_channels(k)], motion.channels[:, sk.joint_channels(j)], atol=1e-4
        )
        np.testing.assert_allclose(back.skeleton.offsets[k], sk.offsets[j], atol=1e-6)


def test_written_file_has_usual_permissions(tmp_path, cmu_short):
    import os
    import stat

    write_bvh(tmp_path / "p.bvh", cmu_short)
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE((tmp_path / "p.bvh").stat().st_mode) == 0o666 & ~umask
