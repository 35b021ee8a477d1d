import gzip
from pathlib import Path

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
        (
            lambda t: t.replace("0 92 0 0 0 0 12 22 179", "0 92 0 0 0 0 12 22"),
            ":21: expected 9 values per frame, got 8 (truncated file?)",
        ),
        (lambda t: t + "# exported by tool\n", ":22: expected 9 values per frame, got 4 (text after the last frame?)"),
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
        "cut-last-line",
        "trailing-text",
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
    assert "\nMOTION\nFrames: 600\nFrame Time: 0.0083333\n" in text  # the source file says .0083333
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


# --- Hardened parser: every BVH case of issue 14 ("Why") -------------------------------------------------


def _read_text(tmp_path, text: str | bytes, name: str = "case.bvh"):
    path = tmp_path / name
    if isinstance(text, str):
        text = text.encode("utf-8")
    path.write_bytes(gzip.compress(text) if name.endswith(".gz") else text)
    return path, read_bvh(path, cm_per_unit=1.0)


def _error(tmp_path, text: str | bytes, name: str = "case.bvh") -> str:
    with pytest.raises(MocapFileError) as err:
        _read_text(tmp_path, text, name)
    message = str(err.value)
    assert str(tmp_path / name) in message
    return message


@pytest.mark.parametrize(
    "edit, message",
    [
        # phantom joint: a JOINT / End Site line not followed by "{"
        (
            lambda t: t.replace("\tJOINT Leg\n\t{\n", "\tJOINT Leg\n"),
            ":7: JOINT 'Leg' (line 6) must be followed by '{'",
        ),
        (lambda t: t.replace("End Site\n\t\t{", "End Site\n"), "End Site of 'Leg' (line 10) must be followed by '{'"),
        # swapped and unbalanced braces
        (
            lambda t: t.replace("\t{\n\t\tOFFSET 0 -10 0\n\t\tCHANNELS", "\t}\n\t\tOFFSET 0 -10 0\n\t\tCHANNELS"),
            ":7: JOINT",
        ),
        (lambda t: t.replace("\t\t}\n\t}\n}", "\t\t}\n}"), ":15: MOTION before the hierarchy's braces are closed"),
        (lambda t: t.replace("\t}\n}\nMOTION", "\t}\n}\n}\nMOTION"), "unexpected '}' after the ROOT's closing brace"),
        (lambda t: t.replace("ROOT Hips\n{", "ROOT Hips\n}"), ":3: ROOT 'Hips' (line 2) must be followed by '{'"),
        # missing OFFSET: leaf End Site, joint with children
        (lambda t: t.replace("\t\t\tOFFSET 0 -10 0\n", ""), ":12: End Site of 'Leg' (line 10) has no OFFSET"),
        (lambda t: t.replace("\t\tOFFSET 0 -10 0\n", "", 1), "JOINT 'Leg' (line 6) has no OFFSET before its End Site"),
        (lambda t: t.replace("\tOFFSET 0 0 0\n", ""), ":5: ROOT 'Hips' (line 2) has no OFFSET before its first child"),
        # numbers: only plain ASCII decimals
        (lambda t: t.replace("OFFSET 0 -10 0", "OFFSET 0 1_000 0", 1), ":8: OFFSET values are not numbers: '1_000'"),
        (lambda t: t.replace("OFFSET 0 -10 0", "OFFSET 0 \u0661\u0662 0", 1), ":8: OFFSET values are not numbers"),
        (
            lambda t: t.replace("OFFSET 0 -10 0", "OFFSET 0 nan 0", 1),
            ":8: OFFSET values are not numbers: 'nan' is not finite",
        ),
        (
            lambda t: t.replace("OFFSET 0 -10 0", "OFFSET 0 1e999 0", 1),
            ":8: OFFSET values are not numbers: '1e999' is not finite",
        ),
        (lambda t: t.replace("11 21 31", "11 1_000 31"), ":20: '1_000' is not a number"),
        (lambda t: t.replace("11 21 31", "11 \u0662\u0661 31"), ":20: '\u0662\u0661' is not a number"),
        (lambda t: t.replace("11 21 31", "11 0x1p3 31"), ":20: '0x1p3' is not a number"),
        (lambda t: t.replace("11 21 31", "11 1e999 31"), ":20: frame 2 channel Leg.Xrotation is inf"),
        (lambda t: t.replace("11 21 31", "11 -inf 31"), ":20: frame 2 channel Leg.Xrotation is -inf"),
        # frame time: tiny, zero, negative, infinite, not a number
        (lambda t: t.replace("0.0333333", "1e-320"), ":18: 'Frame Time:' must be between 1e-06 and 3600 seconds"),
        (lambda t: t.replace("0.0333333", "0"), ":18: 'Frame Time:' must be between"),
        (lambda t: t.replace("0.0333333", "-0.01"), ":18: 'Frame Time:' must be between"),
        (lambda t: t.replace("0.0333333", "inf"), ":18: 'Frame Time:': 'inf' is not finite"),
        (lambda t: t.replace("0.0333333", "1e999"), ":18: 'Frame Time:': '1e999' is not finite"),
        (lambda t: t.replace("0.0333333", "fast"), ":18: 'Frame Time:': 'fast' is not a plain decimal number"),
        (lambda t: t.replace("Frames: 3", "Frames: 3.5"), ":17: 'Frames:' must be an integer, got '3.5'"),
        # duplicate names; channel names and counts
        (lambda t: t.replace("JOINT Leg", "JOINT Hips"), ":6: joint name 'Hips' is already used at line 2"),
        (
            lambda t: t.replace("Zrotation Xrotation Yrotation", "Zrotation Xrotation Xrotation"),
            ":9: a channel is listed twice",
        ),
        (lambda t: t.replace("CHANNELS 3", "CHANNELS three"), ":9: CHANNELS needs a count, got 'three'"),
        (lambda t: t.replace("CHANNELS 3", "CHANNELS 2"), ":9: CHANNELS says 2 but lists 3 names"),
        (
            lambda t: t.replace(
                "\t\tCHANNELS 3 Zrotation Xrotation Yrotation\n", "\t\tCHANNELS 2 Zrotation Xrotation\n"
            ),
            ":19: expected 8 values per frame, got 9",
        ),
        # other grammar errors
        (lambda t: t.replace("End Site", "End Sight"), ":10: unexpected 'End' in HIERARCHY"),
        (
            lambda t: t.replace("\t\tEnd Site", "\t\tCHANNELS 1 Xrotation\n\t\tEnd Site"),
            ":10: second CHANNELS in JOINT 'Leg'",
        ),
        (
            lambda t: t.replace("\t\t\tOFFSET 0 -10 0", "\t\t\tOFFSET 0 -10 0\n\t\t\tCHANNELS 1 Xrotation"),
            ":13: CHANNELS inside an End Site",
        ),
        (lambda t: t.replace("MOTION", "MOTION\nROOT Again"), ":17: expected 'Frames:', got 'ROOT Again'"),
        (
            lambda t: t.replace("}\nMOTION", "}\nROOT B\n{\n\tOFFSET 0 0 0\n}\nMOTION"),
            ":16: more than one ROOT is not supported",
        ),
        (lambda t: "\0" + t, ":1: binary data (NUL byte), not a BVH text file"),
        (lambda t: t.replace("11 21 31", "11 21\x1c31"), ":20: expected 9 values per frame, got 8"),
        (lambda t: t.replace("11 21 31", "11 21 3\x011"), ":20: '3\\x011' is not a number"),
        (lambda t: t.replace("11 21 31", "11 21 31\x7f"), ":20: '31\\x7f' is not a number"),
    ],
    ids=lambda v: None if callable(v) else v[:40],
)
def test_malformed_hierarchy_and_numbers_name_file_and_line(tmp_path, edit, message):
    assert message in _error(tmp_path, edit(GOOD))


@pytest.mark.parametrize(
    "edit",
    [
        lambda t: "\ufeff" + t,  # UTF-8 byte-order mark
        lambda t: t.replace("Frame Time:", "Frame\tTime:"),
        lambda t: t.replace("Frames: 3", "Frames:\t3").replace("Frame Time: ", "Frame  Time:"),
        lambda t: t.replace("\n", "\r\n"),  # Windows line ends
        lambda t: t.replace("\n", "\r"),  # classic Mac line ends
        lambda t: t.replace("\n", "\n\n  \t\n"),  # blank lines everywhere
        lambda t: t.replace("\t", "    ").replace(" 0 0 0 0 ", "\t0\t0  0 0 "),  # spaces for tabs, tabs in data
        lambda t: t.replace("End Site", "END SITE").replace("OFFSET", "Offset").replace("MOTION", "Motion"),
        lambda t: t.rstrip("\n"),  # no newline at the end
    ],
    ids=["bom", "frame-tab-time", "header-spacing", "crlf", "cr", "blank-lines", "tabs", "keyword-case", "no-eol"],
)
def test_harmless_variants_are_accepted(tmp_path, edit):
    reference = parse_bvh(GOOD, "good.bvh", cm_per_unit=1.0, unwrap=False)
    _, motion = _read_text(tmp_path, edit(GOOD))
    assert motion.skeleton.topology() == reference.skeleton.topology()
    np.testing.assert_array_equal(motion.skeleton.offsets, reference.skeleton.offsets)
    np.testing.assert_array_equal(motion.channels[:, :8], reference.channels[:, :8])
    assert motion.fps == 30.0


def test_duplicate_joint_names_are_never_written(tmp_path):
    """The writer orders columns by joint index, and refuses names that would not read back as themselves."""
    from mocapnet.motion import Motion, Skeleton

    def motion(names):
        sk = Skeleton(names, (-1, 0, 0), np.zeros((3, 3)), (("Xrotation",), ("Yrotation",), ("Zrotation",)))
        return Motion(sk, np.array([[1.0, 2.0, 3.0]]), 30.0, "dup")

    for names, reason in [
        (("Hips", "Arm", "Arm"), "joints 1 and 2 are both named 'Arm'"),
        (("Hips", "Arm", " Leg"), "has leading, trailing or repeated whitespace"),
        (("Hips", "Arm", "Le{g"), "contains a brace or a control character"),
        (("Hips", "Arm", ""), "is empty"),
    ]:
        with pytest.raises(MocapFileError, match=reason) as err:
            write_bvh(tmp_path / "dup.bvh", motion(names))
        assert str(tmp_path / "dup.bvh") in str(err.value)
        with pytest.raises(ValueError, match=reason):
            format_bvh(motion(names))
    assert not (tmp_path / "dup.bvh").exists()
    write_bvh(tmp_path / "ok.bvh", motion(("Hips", "Left Arm", "Arm")))
    back = read_bvh(tmp_path / "ok.bvh", unwrap=False)
    assert back.skeleton.names == ("Hips", "Left Arm", "Arm")
    np.testing.assert_array_equal(back.channels, [[1.0, 2.0, 3.0]])


def test_writer_refuses_a_skeleton_it_cannot_write_whole(tmp_path):
    from mocapnet.motion import Motion, Skeleton

    chans = (("Xrotation",),) * 3
    for parents, reason in [((-1, 0, -1), "exactly one root"), ((-1, 2, 1), "2 joints not below the root")]:
        sk = Skeleton(("a", "b", "c"), parents, np.zeros((3, 3)), chans)
        with pytest.raises(MocapFileError, match=reason):
            write_bvh(tmp_path / "x.bvh", Motion(sk, np.zeros((1, 3)), 30.0))


def _chain(n_joints: int, chain: bool = True):
    from mocapnet.motion import Motion, Skeleton

    rng = np.random.default_rng(1)
    parents = tuple(j - 1 if chain else (int(rng.integers(0, j)) if j else -1) for j in range(n_joints))
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),) + (
        ("Zrotation", "Xrotation", "Yrotation"),
    ) * (n_joints - 1)
    leaves = tuple(sorted(set(range(n_joints)) - set(parents)))  # an End Site on each
    names = tuple(f"j{j}" for j in range(n_joints))
    sk = Skeleton(names, parents, rng.normal(size=(n_joints, 3)), channels, rng.normal(size=(len(leaves), 3)), leaves)
    return Motion(sk, np.round(rng.uniform(-170, 170, (3, sk.n_channels)), 6), 60.0, "chain")


def test_deep_hierarchy_reads_and_writes_without_recursion(tmp_path):
    """A 1,500-level chain (beyond Python's default recursion limit) writes and reads back."""
    motion = _chain(1500)
    write_bvh(tmp_path / "deep.bvh.gz", motion)
    back = read_bvh(tmp_path / "deep.bvh.gz", unwrap=False)
    assert back.skeleton.parents == motion.skeleton.parents
    np.testing.assert_array_equal(back.channels, motion.channels)
    assert 0.01 < back.skeleton.cm_per_unit  # the unit guess walks the chain iteratively too


def test_ten_thousand_joint_hierarchy_parses_in_linear_time():
    """10,000 joints (5,000 End Sites) parse well under a second with the defaults, unit guess included
    (``scripts/bench_bvh_io.py`` records the time, and the older reader's with ``--baseline``)."""
    import time

    text = format_bvh(_chain(10_000, chain=False))
    start = time.process_time()
    motion = parse_bvh(text, "big.bvh")
    elapsed = time.process_time() - start
    assert motion.skeleton.n_joints == 10_000
    assert elapsed < 2.0, f"10k-joint parse took {elapsed:.2f} s CPU"


def _bomb(tmp_path: Path, name: str, payload: bytes, repeat: int) -> Path:
    """A .bvh.gz whose content is ``payload`` followed by ``repeat`` copies of 1 MiB blocks, streamed."""
    path = tmp_path / name
    block = payload[-1:] * (1 << 20)
    with gzip.open(path, "wb", compresslevel=9) as fh:
        fh.write(payload)
        for _ in range(repeat):
            fh.write(block)
    return path


def test_gzip_bombs_fail_fast_with_little_memory(tmp_path):
    """A gzip of NULs stops at the first chunk; one of valid-looking text stops at the size limit."""
    import time
    import tracemalloc

    nul = _bomb(tmp_path, "nul.bvh.gz", b"\0", 100)  # 100 MiB of NULs in ~100 kB
    header = GOOD[: GOOD.index("0 90")].encode()
    spaces = _bomb(tmp_path, "spaces.bvh.gz", header + b" ", 24)
    tracemalloc.start()
    start = time.process_time()
    with pytest.raises(MocapFileError, match=r"nul\.bvh\.gz:1: binary data \(NUL byte\)"):
        read_bvh(nul)
    with pytest.raises(MocapFileError, match=r"spaces\.bvh\.gz: decompresses to more than the 16,777,216-byte"):
        read_bvh(spaces, max_bytes=16 << 20)
    elapsed = time.process_time() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert elapsed < 5.0
    assert peak < 100 << 20, f"peak {peak / 2**20:.0f} MiB"


def test_damaged_gzip_is_a_file_error(tmp_path):
    data = bytearray(gzip.compress(GOOD.encode() * 20))
    cases = {
        "flipped.bvh.gz": data[:30] + bytes(b ^ 0xFF for b in data[30:60]) + data[60:],  # deflate stream
        "crc.bvh.gz": data[:-8] + bytes(4) + data[-4:],  # CRC-32 mismatch
        "header.bvh.gz": b"\x1f\x8b\x09" + data[3:],  # unknown compression method
        "notgzip.bvh.gz": GOOD.encode(),
        "junk.bvh.gz": bytes(data) + b"junk",  # bytes after the last member
        "cut.bvh.gz": bytes(data[:-5]),
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(bytes(content))
        with pytest.raises(MocapFileError) as err:
            read_bvh(tmp_path / name)
        assert str(tmp_path / name) in str(err.value)
    # harmless: several gzip members, zero padding after the data, gzip without the .gz suffix
    half = GOOD.index("0 91")
    for name, content in [
        ("members.bvh.gz", gzip.compress(GOOD[:half].encode()) + gzip.compress(GOOD[half:].encode())),
        ("padded.bvh.gz", gzip.compress(GOOD.encode()) + bytes(64)),
        ("magic.bvh", gzip.compress(GOOD.encode())),
    ]:
        (tmp_path / name).write_bytes(content)
        assert read_bvh(tmp_path / name).n_frames == 3


def test_huge_line_is_named_without_huge_memory(tmp_path):
    """A 50 MB MOTION line (newlines lost) is refused naming its line, using a few times its size in memory."""
    import tracemalloc

    text = GOOD[: GOOD.index("0 90")].encode() + b"1.000000 " * (50_000_000 // 9) + b"\n"
    tracemalloc.start()
    with pytest.raises(MocapFileError, match=r"huge\.bvh:19: expected 9 values per frame, got 5,555,555"):
        parse_bvh(text, "huge.bvh")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 400 << 20, f"peak {peak / 2**20:.0f} MiB"


def test_error_messages_quote_at_most_40_characters(tmp_path):
    huge = "x" * 1_000_000
    for text in [
        GOOD.replace("11 21 31", f"11 {huge} 31"),
        GOOD.replace("OFFSET 0 -10 0", f"OFFSET 0 {huge[:3000]} 0", 1),
        GOOD.replace("JOINT Leg", f"JOINT {huge[:3000]}}}"),
        GOOD.replace("Frames: 3", f"Frames: {huge[:3000]}"),
        GOOD.replace("0.0333333", huge[:3000]),
        GOOD.replace("ROOT Hips", "ROOT Hips\n" + huge),
    ]:
        message = _error(tmp_path, text)
        assert "x" * 41 not in message and len(message) < 300 + len(str(tmp_path)), message
        assert f"{tmp_path / 'case.bvh'}:" in message and message.split(":")[1].strip().isdigit()


def test_fixed_point_and_general_paths_agree():
    """The vectorised %.Nf reader and numpy.loadtxt give the same doubles (sign of zero included)."""
    import io

    from mocapnet.io.decimal_text import parse_fixed_point as _parse_fixed_point

    rng = np.random.default_rng(3)
    for decimals in (1, 4, 6, 8):
        values = np.round(rng.normal(0, 10.0 ** rng.integers(0, 5), (40, 7)), decimals)
        values[0, :3] = [0.0, -0.0, -(10.0**-decimals)]
        body = "\n".join(" ".join(f"{v:.{decimals}f}" for v in row) for row in values).encode()
        fast = _parse_fixed_point(body, 7)
        slow = np.loadtxt(io.StringIO(body.decode()), ndmin=2)
        assert fast is not None
        np.testing.assert_array_equal(fast, slow)
        np.testing.assert_array_equal(np.signbit(fast), np.signbit(slow))
    declined = [b"1.50 -.25", b"1.50 2e1", b"1.50 2.50 3.00", b"1.50 -+2.50", b"1.5x 2.5", b"1.5 2.5\x0c", b"nan 1.5"]
    declined += [b"1.50 \xd9\xa1.50", b"1-2.50 1.50", b"1e5.5 1", b"1.5.5 1", b"0x10 1", b"1_0 1", b"1.5 2.25"]
    declined += [b"1.123456789 2.123456789", b"123456789.5 1.5", b"5 1.5", b"1.5e-06 2.5"]
    for text in declined:
        assert _parse_fixed_point(text + b"\n", 2) is None, text
    for text in [b"+1.50 -0.00", b"12345678.5 -1.0", b"\t1.5\t\t2.5  \n\n3.5 4.5", b"007.5 -1.0"]:
        fast = _parse_fixed_point(text, 2)
        slow = np.loadtxt(io.StringIO(text.decode()), ndmin=2)
        np.testing.assert_array_equal(fast, slow)
        np.testing.assert_array_equal(np.signbit(fast), np.signbit(slow))


def test_frames_in_blocks_equal_one_pass(cmu):
    from mocapnet.io.decimal_text import parse_fixed_point, parse_frames

    text = format_bvh(cmu.with_channels(cmu.channels[:300])).encode()
    start = text.index(b"\n", text.index(b"Frame Time")) + 1
    whole = parse_fixed_point(text, cmu.skeleton.n_channels, start)
    for block in (1, 500, 4096, 1 << 20):
        blocks = parse_frames(text, cmu.skeleton.n_channels, start, block_bytes=block)
        assert blocks is not None and np.array_equal(blocks, whole), block
        last = text.rindex(b"\n", 0, len(text) - 1) + 1
        mixed = text[:last] + b"1e5 " + text[last:].split(b" ", 1)[1]  # the last block takes the general parser
        blocks = parse_frames(mixed, cmu.skeleton.n_channels, start, block_bytes=block)
        assert blocks is not None and np.array_equal(blocks[:-1], whole[:-1]) and blocks[-1, 0] == 1e5, block
    damaged = text[:-30] + b"1e5x " + text[-26:]
    assert parse_frames(damaged, cmu.skeleton.n_channels, start, block_bytes=500) is None


def test_written_file_keeps_the_sources_frame_time_names_encoding_and_empty_channel_lines(tmp_path):
    """What a reader keeps so a cleaned file says what its source said: the Frame Time's own digits (``fps`` rounds
    0.0333333 s to 30; writing 1 / 30 would change the text and the clip's length), joint names in the source's
    encoding (Latin-1 stays Latin-1), and a joint with no channels written with ``CHANNELS 0`` (other readers,
    e.g. PyPI ``bvh``, require the line)."""
    text = GOOD.replace("JOINT Leg", "JOINT Cabe\xe7a").replace(
        "\t\tCHANNELS 3 Zrotation Xrotation Yrotation\n", "\t\tCHANNELS 0\n"
    )
    text = text.replace("0 90 0 0 0 0 10 20 30", "0 90 0 0 0 0").replace("0 91 0 0 0 0 11 21 31", "0 91 0 0 0 0")
    text = text.replace("0 92 0 0 0 0 12 22 179", "0 92 0 0 0 0")
    src = tmp_path / "latin.bvh"
    src.write_bytes(text.encode("latin-1"))
    m = read_bvh(src, cm_per_unit=1.0)
    assert m.fps == 30.0 and m.frame_time == 0.0333333 and m.encoding == "latin-1"
    assert m.skeleton.names[1] == "Cabe\xe7a" and m.skeleton.channels[1] == ()
    write_bvh(tmp_path / "out.bvh", m)
    raw = (tmp_path / "out.bvh").read_bytes()
    assert b"JOINT Cabe\xe7a" in raw and b"Frame Time: 0.0333333\n" in raw
    assert b"\t\tCHANNELS 0\n" in raw
    again = read_bvh(tmp_path / "out.bvh", cm_per_unit=1.0)
    assert again.skeleton.names == m.skeleton.names and again.frame_time == 0.0333333
    # a motion whose rate changed is written at its own rate; one made in memory, UTF-8 and 1 / fps
    import dataclasses

    write_bvh(tmp_path / "fast.bvh", dataclasses.replace(m, fps=60.0))
    assert b"Frame Time: 0.016666667\n" in (tmp_path / "fast.bvh").read_bytes()
    fresh = dataclasses.replace(m, frame_time=None, encoding="utf-8")
    write_bvh(tmp_path / "utf8.bvh", fresh)
    raw = (tmp_path / "utf8.bvh").read_bytes()
    assert "JOINT Cabe\xe7a".encode() in raw and b"Frame Time: 0.033333333\n" in raw
