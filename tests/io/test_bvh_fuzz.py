"""Property-based and mutation tests of the BVH reader and writer (issue 14).

* hypothesis: generated skeletons and motions round-trip exactly; mutated files round-trip or raise
  ``MocapFileError`` naming the file; the fixed-point fast path equals ``numpy.loadtxt``.
* seeded mutations of real BVH files (the shared corpora when present, else the shipped CMU clip): truncation,
  deleted / duplicated / swapped lines, garbage and non-finite numbers, wrong channel counts, broken braces,
  duplicate names, bad headers, stray bytes, damaged gzip. Every case round-trips or raises ``MocapFileError``
  naming the file (and the line, for text damage) within 5 s. ``scripts/fuzz_bvh.py`` runs 600 of them.
"""

from __future__ import annotations

import gzip
import io
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocapnet.corpus import PACKAGE_DATA
from mocapnet.io import MocapFileError, read_bvh, write_bvh
from mocapnet.io.bvh import format_bvh, parse_bvh
from mocapnet.io.decimal_text import parse_fixed_point as _parse_fixed_point
from mocapnet.motion import CHANNEL_NAMES, Motion, Skeleton

FUZZ_SETTINGS = settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
SECONDS_PER_CASE = 5.0

# --- generated skeletons and motions ----------------------------------------------------------------------

_NAME = st.text(alphabet="abcXYZ019_:-.éü日 ", min_size=1, max_size=10).map(lambda s: " ".join(s.split())).filter(bool)


@st.composite
def motions(draw) -> Motion:
    """A random tree of 1-12 joints, any channel subset and order, end sites, 1-5 frames of %.6f values."""
    n = draw(st.integers(1, 12))
    names = tuple(draw(st.lists(_NAME, min_size=n, max_size=n, unique=True)))
    parents = tuple([-1] + [draw(st.integers(0, j - 1)) for j in range(1, n)])
    channels = tuple(
        tuple(draw(st.permutations(CHANNEL_NAMES))[: draw(st.integers(1 if j == 0 else 0, 6))]) for j in range(n)
    )
    offsets = np.array(draw(st.lists(st.integers(-99999, 99999), min_size=3 * n, max_size=3 * n))).reshape(n, 3)
    end_parents = tuple(sorted(draw(st.sets(st.integers(0, n - 1)))))
    end_sites = np.array([[draw(st.integers(-9999, 9999)) / 100.0 for _ in range(3)] for _ in end_parents])
    skeleton = Skeleton(names, parents, offsets / 1000.0, channels, end_sites.reshape(-1, 3), end_parents)
    frames = draw(st.integers(1, 5))
    values = draw(
        st.lists(
            st.integers(-(10**9), 10**9), min_size=frames * skeleton.n_channels, max_size=frames * skeleton.n_channels
        )
    )
    fps = draw(st.sampled_from([24.0, 25.0, 30.0, 60.0, 120.0, 29.97]))
    return Motion(skeleton, np.array(values, dtype=float).reshape(frames, -1) / 1e6, fps, "generated")


def assert_same_motion(back: Motion, motion: Motion, atol: float = 0.0) -> None:
    """Same joints (matched by name: the file lists them depth-first), channels, offsets, end sites and rate."""
    sk, bk = motion.skeleton, back.skeleton
    assert sorted(bk.names) == sorted(sk.names)
    index = {name: k for k, name in enumerate(bk.names)}
    for j, name in enumerate(sk.names):
        k = index[name]
        assert bk.channels[k] == sk.channels[j]
        assert (sk.parents[j] < 0 and bk.parents[k] < 0) or bk.names[bk.parents[k]] == sk.names[sk.parents[j]]
        np.testing.assert_allclose(bk.offsets[k], sk.offsets[j], rtol=1e-9, atol=atol)
        np.testing.assert_allclose(
            back.channels[:, bk.joint_channels(k)], motion.channels[:, sk.joint_channels(j)], rtol=1e-9, atol=atol
        )
    assert sorted(bk.names[p] for p in bk.end_parents) == sorted(sk.names[p] for p in sk.end_parents)
    assert back.fps == pytest.approx(motion.fps, rel=1e-6)


@FUZZ_SETTINGS
@given(motions())
def test_generated_motions_round_trip_exactly(motion):
    back = parse_bvh(format_bvh(motion), "gen.bvh", cm_per_unit=1.0, unwrap=False)
    assert_same_motion(back, motion)


def _mutate(text: bytes, position: int, cut: int, insert: bytes) -> bytes:
    position %= len(text) + 1
    return text[:position] + insert + text[position + cut :]


@FUZZ_SETTINGS
@given(
    motions(),
    st.integers(0, 10**6),
    st.integers(0, 40),
    st.one_of(
        st.binary(max_size=6),
        st.sampled_from([b"{", b"}", b"\n", b"nan", b"1_0", b"\xd9\xa1", b"JOINT x\n", b"End Site\n", b"\r", b"\0"]),
    ),
)
def test_mutated_files_round_trip_or_name_the_file(motion, position, cut, insert):
    text = _mutate(format_bvh(motion).encode(), position, cut, insert)
    try:
        back = parse_bvh(text, "mutant.bvh", cm_per_unit=1.0, unwrap=False)
    except MocapFileError as exc:
        assert re.match(r"mutant\.bvh:\d+: ", str(exc)), str(exc)
        return
    again = parse_bvh(format_bvh(back), "again.bvh", cm_per_unit=1.0, unwrap=False)
    assert_same_motion(again, back, atol=1e-6)


_TOKEN = st.one_of(
    st.integers(-(10**8), 10**8).map(lambda m: f"{m / 1e4:.4f}"),
    st.integers(-(10**17), 10**17).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda v: f"{v:g}"),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(["0.0000", "-0.0000", "+1.5000", "1.50", ".5000", "1.", "-", "1e3", "nan", "12", "1.0000.0000"]),
    st.sampled_from(["1e", "1e+", "-1E-07", "1.5e3.5", "1.e5", "0e0", "-0", "1e999", "9" * 17, "0." + "0" * 12 + "1"]),
)


@FUZZ_SETTINGS
@given(st.lists(st.lists(_TOKEN, min_size=3, max_size=3), min_size=1, max_size=6), st.sampled_from([" ", "\t", "  "]))
def test_fixed_point_path_equals_loadtxt_or_declines(rows, separator):
    body = "\n".join(separator.join(row) for row in rows).encode()
    fast = _parse_fixed_point(body, 3)
    if fast is None:
        return
    slow = np.loadtxt(io.StringIO(body.decode()), ndmin=2, comments=None)
    np.testing.assert_array_equal(fast, slow)
    np.testing.assert_array_equal(np.signbit(fast), np.signbit(slow))


# --- seeded mutations of real files ----------------------------------------------------------------------

_GARBAGE = [
    b"abc",
    b"1_000",
    "\u0661\u0662\u0663".encode(),
    b"0x1p3",
    b"1e",
    b"--1",
    b"1.2.3",
    "\u221e".encode(),
    b"1,5",
    b"x" * 100_000,
    b"\xff\xfe",
    b"1e5",
    b"+.5",
    b"12",
]
_NON_FINITE = [b"nan", b"NaN", b"inf", b"-inf", b"1e999", b"-1e999", b"Infinity"]
_HEADER_VALUES = [b"0", b"-1", b"1e-320", b"inf", b"nan", b"abc", b"99999999999", b"1", b"", b"3.5"]


def _line_indices(lines: list[bytes], keyword: bytes) -> list[int]:
    return [i for i, line in enumerate(lines) if line.split()[:1] == [keyword]]


def _first_motion_line(lines: list[bytes]) -> int:
    return next(i for i, line in enumerate(lines) if line.strip().upper() == b"MOTION") + 3


def _edit_lines(
    text: bytes, rng: np.random.Generator, edit: Callable[[list[bytes], np.random.Generator], None]
) -> bytes:
    lines = text.split(b"\n")
    edit(lines, rng)
    return b"\n".join(lines)


def _pick(rng: np.random.Generator, items: list):
    return items[int(rng.integers(len(items)))]


def _replace_token(lines: list[bytes], rng: np.random.Generator, choices: list[bytes]) -> None:
    """Replace one number: in a frame line (most often) or an OFFSET, or the frame-time value."""
    where = rng.random()
    if where < 0.7:
        i = int(rng.integers(_first_motion_line(lines), len(lines) - 1))
    elif where < 0.9:
        i = _pick(rng, _line_indices(lines, b"OFFSET"))
    else:
        i = _first_motion_line(lines) - 1
    tokens = lines[i].split()
    if tokens:
        tokens[int(rng.integers(1 if not tokens[0][:1].isdigit() else 0, len(tokens)))] = _pick(rng, choices)
        lines[i] = b" ".join(tokens)


def _channels(lines: list[bytes], rng: np.random.Generator) -> None:
    i = _pick(rng, _line_indices(lines, b"CHANNELS"))
    tokens = lines[i].split()
    choice = int(rng.integers(4))
    if choice == 0:
        tokens[1] = str(int(tokens[1]) + _pick(rng, [-1, 1])).encode()
    elif choice == 1 and len(tokens) > 2:
        tokens = [tokens[0], str(int(tokens[1]) - 1).encode()] + tokens[2:-1]  # consistent, one channel fewer
    elif choice == 2:
        tokens = tokens + [b"Xrotation"]
    else:
        tokens[-1] = b"Wrotation"
    lines[i] = b" ".join(tokens)


def _braces(lines: list[bytes], rng: np.random.Generator) -> None:
    opens = [i for i, line in enumerate(lines) if line.strip() == b"{"]
    closes = [i for i, line in enumerate(lines) if line.strip() == b"}"]
    choice = int(rng.integers(4))
    if choice == 0:
        del lines[_pick(rng, opens)]
    elif choice == 1:
        del lines[_pick(rng, closes)]
    elif choice == 2:
        a, b = _pick(rng, opens), _pick(rng, closes)
        lines[a], lines[b] = lines[b], lines[a]
    else:
        lines.insert(int(rng.integers(1, _first_motion_line(lines))), _pick(rng, [b"{", b"}"]))


def _duplicate_name(lines: list[bytes], rng: np.random.Generator) -> None:
    joints = _line_indices(lines, b"JOINT") + _line_indices(lines, b"ROOT")
    a, b = rng.choice(joints, 2, replace=False)
    lines[a] = lines[a].split()[0] + b" " + b" ".join(lines[b].split()[1:])


def _header(lines: list[bytes], rng: np.random.Generator) -> None:
    i = _first_motion_line(lines) - int(rng.integers(1, 3))  # "Frame Time:" or "Frames:"
    lines[i] = lines[i].split(b":")[0] + b": " + _pick(rng, _HEADER_VALUES)


def _stray_bytes(text: bytes, rng: np.random.Generator) -> bytes:
    insert = _pick(rng, [b"\0", b"\xef\xbb\xbf", b"\xff", b"\x0c", b"\r", b"\x1a", bytes(rng.integers(0, 256, 6))])
    position = int(rng.integers(len(text)))
    return text[:position] + insert + text[position:]


def _damaged_gzip(text: bytes, rng: np.random.Generator) -> bytes:
    data = bytearray(gzip.compress(text, compresslevel=6))
    choice = int(rng.integers(4))
    if choice == 0:  # flip a run of bytes in the deflate stream
        start = int(rng.integers(10, len(data) - 8))
        data[start : start + 16] = bytes(b ^ 0x5A for b in data[start : start + 16])
    elif choice == 1:  # truncate
        data = data[: int(rng.integers(1, len(data)))]
    elif choice == 2:  # CRC or size trailer
        data[-1 - int(rng.integers(8))] ^= 0xFF
    else:  # header: method or flags
        data[int(rng.integers(2, 4))] ^= 0x0F
    return bytes(data)


MUTATIONS: dict[str, Callable[[bytes, np.random.Generator], bytes]] = {
    "truncate": lambda t, rng: t[: int(rng.integers(len(t)))],
    "delete-line": lambda t, rng: _edit_lines(t, rng, lambda ls, r: ls.pop(int(r.integers(len(ls))))),
    "duplicate-line": lambda t, rng: _edit_lines(t, rng, lambda ls, r: ls.insert(i := int(r.integers(len(ls))), ls[i])),
    "swap-lines": lambda t, rng: _edit_lines(
        t, rng, lambda ls, r: ls.__setitem__(slice(i := int(r.integers(len(ls) - 1)), i + 2), ls[i : i + 2][::-1])
    ),
    "garbage-number": lambda t, rng: _edit_lines(t, rng, lambda ls, r: _replace_token(ls, r, _GARBAGE)),
    "non-finite": lambda t, rng: _edit_lines(t, rng, lambda ls, r: _replace_token(ls, r, _NON_FINITE)),
    "channel-count": lambda t, rng: _edit_lines(t, rng, _channels),
    "braces": lambda t, rng: _edit_lines(t, rng, _braces),
    "duplicate-name": lambda t, rng: _edit_lines(t, rng, _duplicate_name),
    "header": lambda t, rng: _edit_lines(t, rng, _header),
    "stray-bytes": _stray_bytes,
    "damaged-gzip": _damaged_gzip,
}


def fuzz_sources(
    data_root: Path | None, n_files: int, max_frames: int | None, seed: int = 0
) -> list[tuple[str, bytes]]:
    """``(name, text)`` of real BVH files: a seeded sample of the shared corpora, else the shipped clip.

    ``max_frames`` keeps the first frames only (``Frames:`` rewritten) so a case stays fast.
    """
    files = sorted((data_root / "bvh").rglob("*.bvh*")) if data_root and (data_root / "bvh").exists() else []
    if files:
        rng = np.random.default_rng(seed)
        cmu = [f for f in files if "cmu" in str(f)]
        files = cmu[:1] + [files[i] for i in rng.choice(len(files), n_files - len(cmu[:1]), replace=False)]
    else:
        files = [PACKAGE_DATA / "bvh" / "01_01.bvh.gz"]
    sources = []
    for f in files:
        text = gzip.open(f, "rb").read() if f.suffix == ".gz" else f.read_bytes()
        if max_frames is not None:
            head, _, body = text.partition(b"Frame Time:")
            time_line, _, frames = body.partition(b"\n")
            kept = frames.split(b"\n")[:max_frames]
            head = re.sub(rb"Frames:\s*\d+", b"Frames: %d" % len(kept), head)
            text = head + b"Frame Time:" + time_line + b"\n" + b"\n".join(kept) + b"\n"
        sources.append((f.name.removesuffix(".gz"), text))
    return sources


def run_case(folder: Path, index: int, kind: str, name: str, text: bytes, rng: np.random.Generator) -> dict:
    """Mutate ``text`` by ``kind``, read it, round-trip it if it reads; raise AssertionError on any failure."""
    mutated = MUTATIONS[kind](text, rng)
    gz = kind == "damaged-gzip" or rng.random() < 0.3
    path = folder / f"case{index:04d}_{kind}_{name.removesuffix('.bvh')}.bvh{'.gz' if gz else ''}"
    path.write_bytes(gzip.compress(mutated, compresslevel=1) if gz and kind != "damaged-gzip" else mutated)
    start = time.perf_counter()
    try:
        motion = read_bvh(path)
    except MocapFileError as exc:
        message = str(exc)
        assert str(path) in message, f"{kind}: error does not name the file: {message[:200]}"
        if kind != "damaged-gzip":
            assert re.match(re.escape(str(path)) + r":\d+: ", message), f"{kind}: error names no line: {message}"
        outcome = "error"
    else:
        out = path.with_name("rt_" + path.name)
        write_bvh(out, motion)
        assert_same_motion(read_bvh(out, cm_per_unit=motion.skeleton.cm_per_unit), motion, atol=1e-6)
        out.unlink()
        message, outcome = "", "round-trip"
    seconds = time.perf_counter() - start
    assert seconds < SECONDS_PER_CASE, f"{path.name} took {seconds:.1f} s"
    path.unlink()
    return {"case": index, "kind": kind, "source": name, "outcome": outcome, "seconds": seconds, "error": message}


def run_mutations(folder: Path, sources: list[tuple[str, bytes]], n_cases: int, seed: int = 0) -> list[dict]:
    """``n_cases`` mutations cycling through every kind, on sources picked by a seeded generator."""
    rng = np.random.default_rng(seed)
    kinds = list(MUTATIONS)
    results = []
    for index in range(n_cases):
        name, text = sources[int(rng.integers(len(sources)))]
        results.append(run_case(folder, index, kinds[index % len(kinds)], name, text, rng))
    return results


def test_seeded_mutations_of_real_files(tmp_path):
    """120 seeded mutations (10 of each kind) of real files, cut to 150 frames to keep the suite fast."""
    from tests.conftest import SHARED

    results = run_mutations(tmp_path, fuzz_sources(SHARED if SHARED.exists() else None, 6, 150), 120)
    kinds = {r["kind"] for r in results}
    assert kinds == set(MUTATIONS)
    assert {r["outcome"] for r in results} == {"error", "round-trip"}  # both outcomes are exercised
