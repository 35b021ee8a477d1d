"""The vectorised MOTION parsers (``mocapnet.io.decimal_text``): exact (bit for bit ``float(token)``), and
None for anything that is not plain decimal text with a constant count of numbers per line."""

from __future__ import annotations

import gzip
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocapnet.io.decimal_text import parse_decimal, parse_fixed_point, parse_frames

PLAIN = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")  # the grammar of a BVH number


def reference(text: bytes, n_channels: int) -> np.ndarray | None:
    """What the parsers must return: ``float`` of every token, or None when a token is not plain, a value is
    not finite or a non-blank line does not hold ``n_channels`` numbers."""
    rows = [line.split() for line in text.split(b"\n") if line.split()]
    tokens = [t for row in rows for t in row]
    if not rows or any(len(row) != n_channels for row in rows) or not all(PLAIN.fullmatch(t) for t in tokens):
        return None
    values = np.array([float(t) for t in tokens]).reshape(-1, n_channels)
    return values if np.isfinite(values).all() else None


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool((a.view(np.int64) == b.view(np.int64)).all())


_NUMBER = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(lambda v: f"{v:g}"),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(-1e4, 1e4).map(lambda v: f"{v:.6f}"),
    st.floats(-1e4, 1e4).map(lambda v: f"{v:.{len(str(v)) % 17}g}"),
    st.integers(-(10**20), 10**20).map(str),
    st.tuples(st.integers(0, 10**16), st.integers(-340, 340)).map(lambda t: f"{t[0]}e{t[1]}"),
    st.tuples(st.integers(0, 10**8), st.integers(0, 10**9)).map(lambda t: f"-{t[0]}.{t[1]:09d}E+{t[0] % 30}"),
)
_ODD = st.sampled_from(
    ["0", "-0", "+0.0", ".5", "5.", "-.5e-3", "+.5E+3", "1e", "e5", ".", "-", "+", "1-2", "1e5.5", "1.5.5", "--1"]
    + ["1e+-5", "1e5e5", "0x10", "nan", "inf", "1_0", "\u0661", "1.5x", "5-", "-e5", "1e-", "007.50", "1e999"]
    + ["0." + "0" * 20 + "1", "9" * 17, "1" * 8 + "." + "1" * 7, "1" * 9 + ".5", "0.000123457", "1e-0000000005"]
)
_TOKEN = st.one_of(_NUMBER, _NUMBER, _ODD)
_SETTINGS = settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


@_SETTINGS
@given(st.lists(st.lists(_TOKEN, min_size=3, max_size=3), min_size=1, max_size=8), st.sampled_from([" ", "\t", " \t "]))
def test_decimal_parser_is_float_or_declines(rows, separator):
    text = "\n".join(separator.join(row) for row in rows).encode()
    expected = reference(text, 3)
    got = parse_decimal(text, 3)
    if expected is None:
        assert got is None
    else:
        assert got is not None and same_bits(got, expected), (text, got, expected)


@_SETTINGS
@given(st.lists(st.lists(_NUMBER, min_size=1, max_size=4), min_size=1, max_size=6))
def test_decimal_parser_checks_the_count_per_line(rows):
    text = ("\n".join(" ".join(row) for row in rows) + "\n\n").encode()
    expected = reference(text, 4)
    got = parse_decimal(text, 4)
    assert (got is None) == (expected is None)
    if got is not None:
        assert same_bits(got, expected)


def test_decimal_parser_cases():
    text = b"-0 .5 5. +1.5e+3\n\t-2.5E-2  1e-30 0.000123457 123456789.125\n\n"
    got = parse_decimal(text, 4)
    assert same_bits(got, reference(text, 4))
    assert np.signbit(got[0, 0]) and got[0, 0] == 0.0
    body = b"1 2\n3 4\n"
    assert same_bits(parse_decimal(b"Frames: 2\n" + body, 2, start=10), reference(body, 2))
    for bad in [b"1 2\n3\n", b"1 2 3\n", b"1 2\n3 4 5 6\n", b"1 2\x0b\n", b"1 2\r\n", b"", b"\n\n"]:
        assert parse_decimal(bad, 2) is None, bad


def test_frames_take_either_parser_per_block():
    rng = np.random.default_rng(0)
    values = rng.normal(0, 100, (300, 5))
    fixed = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in values[:150])
    general = "\n".join(" ".join(f"{v:g}" for v in row) for row in values[150:])
    text = (fixed + "\n" + general + "\n").encode()
    expected = reference(text, 5)
    for block in (64, 1000, 1 << 20):
        assert same_bits(parse_frames(text, 5, block_bytes=block), expected), block
    assert parse_fixed_point(text, 5) is None  # the one-block case goes through parse_decimal
    assert parse_frames(text + b"1 2 3 4\n", 5, block_bytes=1000) is None
    assert parse_frames(b" \n\n", 5) is None and parse_frames(b"", 5) is None


def test_bandai1_motion_text_parses_exactly(shared):
    """bandai1 writes %g (exponents, integers, varying decimals): the general parser takes every file."""
    files = sorted((shared / "bvh/bandai_namco_1").glob("*.bvh.gz"))[:20]
    if not files:
        pytest.skip("bandai1 not found")
    for path in files:
        raw = gzip.open(path).read()
        start = raw.index(b"\n", raw.index(b"Frame Time:")) + 1
        n_channels = len(raw[start : raw.index(b"\n", start)].split())
        assert parse_fixed_point(raw, n_channels, start) is None
        got = parse_decimal(raw, n_channels, start)
        assert got is not None and same_bits(got, reference(raw[start:], n_channels)), path
