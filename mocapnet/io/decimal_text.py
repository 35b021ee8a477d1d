"""Vectorised parsing of whitespace-separated decimal text (a BVH MOTION block) into float64 frames.

Two numpy parsers, both exact (each value is the double ``float(token)`` returns, sign of zero included) and
both returning None, never raising, for text they do not take, so that the caller can fall back to a slower
reader that names the bad line:

* ``parse_fixed_point``: every number has the same count of decimals (``%.6f``), the usual exporter layout;
* ``parse_decimal``: any plain decimal, ``[+-]digits[.digits][(e|E)[+-]digits]`` (``%g`` writes integers,
  exponents and varying decimals), for every line holding the same count of numbers.

``parse_frames`` runs them over blocks of whole lines, so their index arrays (~10-20 bytes per text byte) stay
small. Digits are read 8 at a time from unaligned 64-bit words (SWAR, ``eight_digits``).
"""

from __future__ import annotations

import re

import numpy as np

# Digits 8 bytes at a time: masks of the last d bytes of a little-endian word (d = 0..8), the
# ASCII '0' in those bytes, and the constants of the digit checks and of ``_eight_digits``.
_HIGH_BYTES = np.array([(2**64 - 1) ^ (2 ** (8 * (8 - d)) - 1) for d in range(9)], dtype=np.uint64)
_HIGH_ZEROS = _HIGH_BYTES & np.uint64(0x3030303030303030)
_PLUS_118 = np.uint64(0x7676767676767676)  # a byte above 9 gets its high bit set (digit values 0-9 do not)
_HIGH_BITS = np.uint64(0x8080808080808080)
_LOW_OF_QUADS = np.uint64(0x000000FF000000FF)
_MUL_HIGH = np.uint64(100 + (1000000 << 32))
_MUL_LOW = np.uint64(1 + (10000 << 32))


def eight_digits(word: np.ndarray) -> np.ndarray:
    """Integer value of 8 decimal digits held one per byte (values 0-9, first byte most significant), uint64.

    The SWAR reduction of Lemire's "parse eight digits": pairs, then quads, then all eight.
    """
    word = word * np.uint64(10) + (word >> np.uint64(8))
    word = ((word & _LOW_OF_QUADS) * _MUL_HIGH + ((word >> np.uint64(16)) & _LOW_OF_QUADS) * _MUL_LOW) >> np.uint64(32)
    return word & np.uint64(0xFFFFFFFF)


def parse_fixed_point(text: bytes, n_channels: int, start: int = 0) -> np.ndarray | None:
    """``[T, n_channels]`` frames when every token is ``[sign]digits.k-digits`` with one k, else None.

    Vectorised over tokens, one per decimal point, using the positions of the bytes below '0' ("specials":
    whitespace, signs, dots): after each dot come exactly k bytes then whitespace; before it 1 to 8 bytes, then
    whitespace or a sign with whitespace before it; those bytes are checked to be digits while they are read,
    8 at a time (``eight_digits``). When the tokens' lengths add up to the count of non-whitespace bytes the
    text holds nothing else. Exactness: a token is an integer m < 10**15 < 2**53 over 10**k, and the IEEE
    division m / 10**k is correctly rounded: the same double ``float(token)`` returns. The frames are
    ``text[start:]``; when 9 bytes precede them, ``text[start - 1]`` is a newline and ``text`` ends with one
    (the usual case), nothing is copied.
    """
    if start < 9 or text[start - 1] != 10:
        text, start = b"\n" * 9 + text[start:], 9
    if text[-1:] != b"\n":
        text += b"\n"
    if text.find(b"e", start) >= 0 or text.find(b"E", start) >= 0:
        return None  # exponents ("%g" files): decline before any work
    a = np.frombuffer(text, np.uint8)[start - 1 :]  # every token has a separator on both sides
    specials = np.flatnonzero(a < 48)
    kinds = a[specials]
    at_dot = np.flatnonzero(kinds == 46)
    n = at_dot.size
    if n == 0 or n % n_channels:
        return None
    dots = specials[at_dot]
    k = int(specials[at_dot[0] + 1] - dots[0] - 1)
    if not 1 <= k <= 8 or (specials[at_dot + 1] - dots != k + 1).any():
        return None
    whole = dots - specials[at_dot - 1] - 1  # bytes between the dot and the special before it
    if whole.min() < 1 or whole.max() > min(8, 15 - k):
        return None
    lead = kinds[at_dot - 1]  # the special before the digits: whitespace or a sign
    negative = lead == 45
    signed = negative | (lead == 43)
    if not (signed | (lead <= 32)).all():
        return None
    n_signed = int(np.count_nonzero(signed))
    if n_signed and (a[(dots - whole - 2)[signed]] > 32).any():
        return None  # a sign must start its token
    newline = kinds == 10
    if np.count_nonzero(kinds < 32) != np.count_nonzero(newline) + np.count_nonzero(kinds == 9):
        return None  # control characters other than tab and newline (CR is gone by now)
    non_space = int(np.count_nonzero(kinds > 32))
    if non_space != n + n_signed or n_signed + int(whole.sum()) + n * (k + 1) != a.size - (kinds.size - non_space):
        return None  # punctuation, stray signs or dots, bytes outside the tokens
    words = np.ndarray((len(text) - 7,), np.dtype("<u8"), text, 0, (1,))  # 8 bytes from every offset
    at = dots + (start - 1)  # offsets of the dots in text
    frac = (words[at + (k - 7)] & _HIGH_BYTES[k]) - _HIGH_ZEROS[k]
    high = (words[at - 8] & _HIGH_BYTES[whole]) - _HIGH_ZEROS[whole]
    if (((frac + _PLUS_118) | frac | (high + _PLUS_118) | high) & _HIGH_BITS).any():
        return None  # a byte that is not a digit (letters, non-ASCII)
    value = (eight_digits(high) * np.uint64(10**k) + eight_digits(frac)).astype(np.float64)
    value /= 10.0**k
    np.negative(value, out=value, where=negative)
    edges = np.concatenate(([0], specials[newline], [a.size]))
    counts = np.diff(np.searchsorted(dots, edges))  # tokens per line
    if not (counts[counts > 0] == n_channels).all():
        return None
    return value.reshape(-1, n_channels)


# parse_decimal: classes of the bytes that are not digits, and the automaton of a token over them. A token is
# [sign] mantissa [exponent]; its non-digit bytes come in this order: sign (M), dot, e/E, exponent sign (X).
_WS, _SIGN, _DOT, _EXP, _BAD = 0, 1, 2, 3, 4
_CLASS = np.full(256, _BAD, np.int16)
_CLASS[[9, 10, 32]] = _WS  # tab, newline, space (CR is gone by now; other control bytes go to the slow reader)
_CLASS[[43, 45]] = _SIGN
_CLASS[46] = _DOT
_CLASS[[69, 101]] = _EXP
_M_SIGN, _X_SIGN, _NO = 5, 6, -1


def _may_follow(kind: int, digits: bool, nxt: int) -> bool:
    """Whether class ``nxt`` may come after ``kind`` (a sign resolved to _M_SIGN / _X_SIGN) with or without
    ``digits`` between them."""
    if kind == _WS:
        return nxt in (_WS, _DOT) or (nxt == _SIGN and not digits) or (nxt == _EXP and digits)
    if kind == _M_SIGN:
        return nxt == _DOT or (nxt in (_EXP, _WS) and digits)
    if kind == _DOT:
        return nxt in (_EXP, _WS)
    if kind == _EXP:
        return (nxt == _SIGN and not digits) or (nxt == _WS and digits)
    return kind == _X_SIGN and nxt == _WS and digits


def _triple_ok(c0: int, r0: bool, c1: int, r1: bool, c2: int) -> bool:
    """Whether three consecutive non-digit bytes of classes c0, c1, c2, with digits between c0 and c1 (r0) and
    between c1 and c2 (r1), fit the grammar at c1. A sign's role follows from what precedes it; a dot needs a
    digit on one side. Checking every consecutive triple checks every token (the first and last bytes are
    whitespace)."""
    if _BAD in (c0, c1, c2) or (c0 == _WS and not _may_follow(_WS, r0, c1)):
        return False
    if c1 == _SIGN:
        c1 = _M_SIGN if c0 == _WS and not r0 else _X_SIGN if c0 == _EXP and not r0 else _NO
    if c1 == _DOT and not (r0 or r1):
        return False
    return _may_follow(c1, r1, c2)


# indexed by (c0 * 2 + r0) * 50 + (c1 * 2 + r1) * 5 + c2
_TRIPLES = np.array(
    [_triple_ok(c0 // 2, c0 % 2, c1 // 2, c1 % 2, c2) for c0 in range(10) for c1 in range(10) for c2 in range(5)]
)
_POW10 = 10.0 ** np.arange(23)  # exact doubles
_SIGNED_POW10 = np.concatenate((_POW10, -_POW10))  # index + 23 for a negative number
_POW10_INT = 10 ** np.arange(16, dtype=np.uint64)
# by nf * 9 + width (nf fraction digits, width = all mantissa digits, <= 7): bytes of the fraction in the word
# ending at the mantissa's end, bytes of the integer part once that word is shifted up by one byte, ASCII zeros
_NW = np.arange(81)
_FRAC_MASK = _HIGH_BYTES[np.minimum(_NW // 9, 8)]
_INT_MASK = _HIGH_BYTES[_NW % 9] ^ _FRAC_MASK
_MANTISSA_ZEROS = _HIGH_ZEROS[_NW % 9]
_TOKEN_RE = re.compile(rb"\S+")
_EIGHT = np.uint64(8)


def _digits(words: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Value of the last ``count`` (0-8) digit bytes of each 64-bit word (ASCII digits, checked by the caller)."""
    words &= _HIGH_BYTES.take(count)
    words -= _HIGH_ZEROS.take(count)
    return eight_digits(words)


def parse_decimal(text: bytes, n_channels: int, start: int = 0) -> np.ndarray | None:
    """``[T, n_channels]`` frames from ``text[start:]`` when every token is a plain decimal
    ``[+-](digits[.digits] | .digits)[(e|E)[+-]digits]`` and every non-blank line has ``n_channels`` of them,
    else None.

    Vectorised over the bytes that are not digits (~2 per token): their classes are checked as consecutive
    triples against the grammar (``_TRIPLES``), which also finds the tokens; the mantissa's digits (the dot
    removed by a shift) and the exponent's are read from 64-bit words. Exactness: a mantissa of at most 15
    digits is an integer m < 2**53 and, for a decimal exponent |q| <= 22, m * 10**q or m / 10**-q is one IEEE
    operation on exact operands (Clinger's fast path): correctly rounded, the double ``float(token)`` returns.
    Other tokens (more digits, larger exponents: none in %g or %f files of sane values) go through ``float``.
    """
    if start < 17 or text[start - 1] != 10:
        text, start = b"\n" * 17 + text[start:], 17
    if text[-1:] != b"\n":
        text += b"\n"
    a = np.frombuffer(text, np.uint8)
    # offsets (in text, minus 8: where the 8-byte word ending at that byte starts) of the non-digit bytes
    s = np.flatnonzero((a[start - 1 :] - np.uint8(48)) > np.uint8(9)).astype(np.int32)
    s += start - 9
    k = a.take(s + 8)
    c = _CLASS.take(k)
    run = s[1:] - s[:-1] > 1  # digits between consecutive specials
    code = c * 2
    code[:-1] += run
    triple = code[:-2] * 50
    triple += code[1:-1] * 5
    triple += c[2:]
    if not _TRIPLES.take(triple).all():
        return None
    token = c[1:] != _WS  # the special starts a token: whitespace followed by a sign, dot, e or digits
    token |= run
    token &= c[:-1] == _WS
    first = np.flatnonzero(token).astype(np.int32)
    n = first.size
    if n == 0 or n % n_channels:
        return None
    newlines = np.flatnonzero(k == 10)
    if newlines.size > 2:
        before = np.cumsum(token, dtype=np.int32).take(newlines[1:] - 1)  # tokens before each line end
        per_line = np.diff(before, prepend=0)
        if not ((per_line == 0) | (per_line == n_channels)).all():
            return None
    j = first + 1  # walk each token's specials: [sign] [dot] [e ...]
    negative = k.take(j) == 45
    signed = c.take(j) == _SIGN
    j += signed
    has_dot = c.take(j) == _DOT
    dot8 = s.take(j)  # the dot, or the mantissa's end when there is none
    j += has_dot
    end8 = s.take(j)  # the mantissa's end: e/E or whitespace
    ni = dot8 - s.take(first)
    ni -= signed
    ni -= 1
    nf = end8 - dot8
    nf -= has_dot
    width = ni + nf
    words = np.ndarray((len(text) - 7,), np.dtype("<u8"), text, 0, (1,))  # 8 bytes from every offset
    word = words[end8 + 1 - has_dot]  # without a dot, the byte after the digits stands in for it
    mask = nf * 9
    mask += width
    np.minimum(mask, 80, out=mask)
    frac = word & _FRAC_MASK.take(mask)
    word <<= _EIGHT
    word &= _INT_MASK.take(mask)
    word |= frac
    word -= _MANTISSA_ZEROS.take(mask)
    m = eight_digits(word)  # right for width <= 7
    long = np.flatnonzero(width > 7)
    slow = None
    if long.size:  # up to 8 integer and 15 fraction digits, from three words
        nf_l, end_l = nf.take(long), end8.take(long)
        frac = _digits(words[end_l], np.minimum(nf_l, 8))
        frac += _digits(words[end_l - 8], np.clip(nf_l - 8, 0, 8)) * np.uint64(10**8)
        frac += _digits(words[dot8.take(long)], np.minimum(ni.take(long), 8)) * _POW10_INT.take(np.minimum(nf_l, 15))
        m[long] = frac
        slow = (width > 15) | (ni > 8)
    np.minimum(nf, 15, out=nf)
    value = m.astype(np.float64)
    value /= _SIGNED_POW10.take(nf + negative * 23)  # exact divisor, one rounding
    with_exp = np.flatnonzero(c.take(j) == _EXP)
    if with_exp.size:
        j = j.take(with_exp) + 1
        exp_signed = c.take(j) == _SIGN
        last8 = s.take(j + exp_signed)  # the whitespace after the exponent
        nx = last8 - end8.take(with_exp)
        nx -= 1
        nx -= exp_signed
        q = _digits(words[last8], np.minimum(nx, 8)).astype(np.int64)
        np.negative(q, out=q, where=k.take(j) == 45)
        q -= nf.take(with_exp)
        outside = (nx > 8) | (q < -22) | (q > 22)
        np.clip(q, -22, 22, out=q)
        scaled = m.take(with_exp).astype(np.float64)
        scaled *= _SIGNED_POW10.take(np.maximum(q, 0) + negative.take(with_exp) * 23)
        scaled /= _POW10.take(np.maximum(-q, 0))
        value[with_exp] = scaled
        if outside.any():
            slow = np.zeros(n, bool) if slow is None else slow
            slow[with_exp] |= outside
    if slow is not None and slow.any():
        for i in np.flatnonzero(slow):
            value[i] = float(_TOKEN_RE.match(text, int(s[first[i]]) + 9).group())
        if not np.isfinite(value).all():
            return None  # "1e999": the caller's slow reader names the line
    return value.reshape(-1, n_channels)


def parse_frames(text: bytes, n_channels: int, start: int = 0, block_bytes: int = 1 << 20) -> np.ndarray | None:
    """``[T, n_channels]`` frames of ``text[start:]`` through ``parse_fixed_point``, else ``parse_decimal``,
    over blocks of whole lines of about ``block_bytes`` (peak memory: the frames plus one block's work); None
    when some block is neither."""
    parts = []
    pos = start
    while pos < len(text):
        end = text.find(b"\n", min(pos + block_bytes, len(text) - 1))
        end = len(text) if end < 0 else end + 1
        low = 0 if pos == start and end == len(text) else max(pos - 17, 0)  # the parsers read 17 bytes back
        block = text if low == 0 and end == len(text) else text[low:end]
        if end - pos < 64 and not block[pos - low :].strip():
            break  # blank lines at the end
        part = parse_fixed_point(block, n_channels, pos - low)
        if part is None:
            part = parse_decimal(block, n_channels, pos - low)
        if part is None:
            return None
        parts.append(part)
        pos = end
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else np.concatenate(parts)
