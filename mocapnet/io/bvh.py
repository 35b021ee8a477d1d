"""BVH read and write for any hierarchy and channel order; ``.bvh`` and gzip-compressed ``.bvh.gz``.

Grammar read (one statement per line; keywords in any case; any ASCII whitespace, CRLF or CR line ends, a
UTF-8 byte-order mark and blank lines accepted)::

    file   := HIERARCHY  ROOT <name> block  MOTION  Frames: <int>  Frame Time: <seconds>  frame*
    block  := "{"  OFFSET <x> <y> <z>  [CHANNELS <n> <n channel names>]  (JOINT <name> block | End Site site)*  "}"
    site   := "{"  OFFSET <x> <y> <z>  "}"
    frame  := one line of <n_channels> numbers

OFFSET and CHANNELS may come in either order but before the first child. Numbers are plain ASCII decimals
(``-12.5``, ``3e-4``); ``1_000``, non-ASCII digits and hex are errors, and so is any non-finite value. Joint
names are unique. Both the parser and the writer are iterative (no recursion), linear in the joint count.

Reading is guarded: ``.gz`` files are decompressed in chunks up to ``max_bytes`` and refused at the first NUL
byte; every error is a ``MocapFileError`` naming the file and line and quoting at most 40 characters.

The MOTION block is read by vectorised exact parsers (``mocapnet.io.decimal_text``): one for numbers that
all have the same count of decimals (``%.6f``, as nearly every exporter writes), one for any plain decimal
(``%g``: integers, exponents); each value is the double ``float(token)`` returns. Text they do not take is
read by ``numpy.loadtxt``; only when that fails is the block scanned line by line to name the offending line.
Rotation channels are unwrapped along time (files that wrap at ±180° become continuous), which leaves every
rotation unchanged.
"""

from __future__ import annotations

import dataclasses
import gzip
import io
import math
import os
import re
import threading
import warnings
import zlib
from collections import deque
from pathlib import Path
from typing import NoReturn

import numpy as np

from mocapnet.io.atomic import MocapFileError, atomic_output
from mocapnet.io.decimal_text import parse_frames
from mocapnet.motion import CHANNEL_NAMES, Motion, Skeleton

# Candidate length units (cm per unit) for a skeleton whose unit is not given: the one that makes the rest
# pose closest to a 170 cm adult (log scale). CMU cgspeed's unit is 1/0.45 inch.
_UNIT_CANDIDATES = {"m": 100.0, "dm": 10.0, "cmu": 2.54 / 0.45, "inch": 2.54, "cm": 1.0, "mm": 0.1}

MAX_BVH_BYTES = 1 << 30
"""Default cap on a BVH file's (decompressed) size in bytes: 1 GiB, ten times the longest clip we know of."""

_CHUNK = 1 << 20  # decompression chunk, bytes
_QUOTE = 40  # characters of a bad token quoted in an error message
_MAX_HIERARCHY_LINE = 4096  # characters; longer HIERARCHY lines are refused before being split
_BLOCK = 1 << 20  # bytes of MOTION text checked at a time when looking for the bad line
_BOM = b"\xef\xbb\xbf"

_FLOAT_RE = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")  # bytes pattern: \d is ASCII only
_NON_FINITE_RE = re.compile(rb"[+-]?(?:nan|inf|infinity)", re.IGNORECASE)
_FLOAT3_RE = re.compile(rb" ".join([_FLOAT_RE.pattern] * 3))
_INT_RE = re.compile(rb"\d+")
_FRAMES_RE = re.compile(rb"frames\s*:(.*)", re.IGNORECASE | re.DOTALL)
_FRAME_TIME_RE = re.compile(rb"frame\s+time\s*:(.*)", re.IGNORECASE | re.DOTALL)
_BAD_BYTE_RE = re.compile(rb"[^\t\n\x0b\x0c\r\x20-\x7e]")  # anything but printable ASCII and whitespace
_NON_SPACE_RE = re.compile(rb"\S")
_INFO_SEPARATORS = (b"\x1c", b"\x1d", b"\x1e", b"\x1f")
_NAME_BAD_RE = re.compile(r"[{}\x00-\x1f\x7f]")
_NUMBERS_RE = re.compile(rb"[\s0-9eE+\-.]*")  # a line of numbers only, perhaps cut short
_MOTION_LINE_RE = re.compile(rb"^[ \t\x0b\x0c]*MOTION[ \t\x0b\x0c]*$", re.MULTILINE | re.IGNORECASE)
_HIERARCHY_CACHE: dict[bytes, tuple[Skeleton, float, int, int]] = {}  # HIERARCHY bytes -> parse result
_HIERARCHY_CACHE_SIZE = 16
_HIERARCHY_LOCK = threading.Lock()
_CHANNEL_BY_BYTES = {c.encode(): c for c in CHANNEL_NAMES}
# A frame rate within this fraction of a whole number is that number (the file's Frame Time is kept for writing).
_FPS_ROUNDING = 1e-3
# Frame time range accepted, seconds: 1 MHz down to one frame an hour.
_FRAME_TIME_RANGE = (1e-6, 3600.0)


def _quote(token: bytes | str) -> str:
    """``token`` quoted for an error message, cut to its first 40 characters."""
    if isinstance(token, bytes):
        token = token[: _QUOTE * 4].decode("utf-8", "replace")
    return repr(token[:_QUOTE]) + ("…" if len(token) > _QUOTE else "")


def _decode_name(raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _read_bytes(path: Path, max_bytes: int) -> bytes:
    """The file's bytes, decompressed when gzip (by suffix or magic number), in chunks, at most ``max_bytes``."""
    try:
        if path.is_dir():
            raise MocapFileError(f"{path}: is a directory, not a BVH file")
        with open(path, "rb") as fh:
            gzipped = path.suffix == ".gz" or fh.read(2) == b"\x1f\x8b"
            fh.seek(0)
            if not gzipped:
                if os.fstat(fh.fileno()).st_size > max_bytes:
                    raise MocapFileError(f"{path}: larger than the {max_bytes:,}-byte limit for a BVH file")
                raw = fh.read()
                nul = raw.find(b"\0")
                if nul >= 0:
                    _binary_error(path, [raw], nul)
                return raw
            if os.fstat(fh.fileno()).st_size > max_bytes:
                raise MocapFileError(f"{path}: larger than the {max_bytes:,}-byte limit for a BVH file")
            return _inflate(path, fh.read(), max_bytes)
    except FileNotFoundError:
        raise MocapFileError(f"{path}: no such file") from None
    except OSError as exc:
        raise MocapFileError(f"{path}: cannot read ({type(exc).__name__}: {str(exc)[:80]})") from None


def _inflate(path: Path, data: bytes, max_bytes: int) -> bytes:
    """Decompress gzip ``data`` (one or more members) 1 MiB at a time: stop at the first NUL byte, at a
    start that is not BVH text, or beyond ``max_bytes``; damaged or truncated data is a ``MocapFileError``."""
    chunks: list[bytes] = []
    total = 0
    inflater = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        while True:
            chunk = inflater.decompress(data, _CHUNK)
            data = inflater.unconsumed_tail
            if chunk:
                nul = chunk.find(b"\0")
                if nul >= 0:
                    _binary_error(path, chunks + [chunk], total + nul)
                total += len(chunk)
                if total > max_bytes:
                    raise MocapFileError(
                        f"{path}: decompresses to more than the {max_bytes:,}-byte limit for a BVH file"
                    )
                if not chunks:
                    _check_start(path, chunk)
                chunks.append(chunk)
            elif inflater.eof:
                data = inflater.unused_data
                if data[:2] == b"\x1f\x8b":  # another gzip member
                    inflater = zlib.decompressobj(16 + zlib.MAX_WBITS)
                elif data.strip(b"\0"):
                    raise MocapFileError(f"{path}: bytes after the end of the gzip data (damaged file?)")
                else:
                    break
            else:
                raise MocapFileError(f"{path}: compressed data ends early (truncated file?)")
    except zlib.error as exc:
        raise MocapFileError(f"{path}: cannot read (damaged gzip data: {str(exc)[:80]})") from None
    return b"".join(chunks)


def _binary_error(path: Path, chunks: list[bytes], at: int) -> NoReturn:
    """Raise for a NUL byte at offset ``at`` of the concatenated ``chunks``."""
    line = 1 + sum(c.count(b"\n") for c in chunks[:-1]) + chunks[-1].count(b"\n", 0, at - sum(map(len, chunks[:-1])))
    raise MocapFileError(f"{path}:{line}: binary data (NUL byte), not a BVH text file")


def _check_start(path: Path, head: bytes) -> None:
    """Fail fast when the first bytes already show this is not BVH text (``head``: the file's start)."""
    body = head.removeprefix(_BOM).lstrip()
    if body and not body[:9].upper() == b"HIERARCHY"[: len(body)]:
        line = 1 + head.count(b"\n", 0, len(head) - len(body))
        raise MocapFileError(f"{path}:{line}: expected 'HIERARCHY' at the start of a BVH file")


def _number(path: Path, lineno: int, token: bytes, what: str) -> float:
    """A plain ASCII decimal number, finite, else an error naming the line."""
    if _FLOAT_RE.fullmatch(token):
        value = float(token)
        if math.isfinite(value):
            return value
    elif not _NON_FINITE_RE.fullmatch(token):
        raise MocapFileError(f"{path}:{lineno}: {what}: {_quote(token)} is not a plain decimal number")
    raise MocapFileError(f"{path}:{lineno}: {what}: {_quote(token)} is not finite")


def _name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a BVH joint name (it would not read back as itself), or None."""
    if not name:
        return "is empty"
    if _NAME_BAD_RE.search(name):
        return "contains a brace or a control character"
    if " ".join(name.split()) != name:
        return "has leading, trailing or repeated whitespace"
    return None


class _Hierarchy:
    """Parser state for the HIERARCHY section: the joints read so far and the stack of open blocks."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[tuple[str, ...]] = []
        self.end_sites: list[list[float]] = []
        self.end_parents: list[int] = []
        self.name_line: dict[str, int] = {}
        # one entry per open block: node (joint index, or ~end-site index), its line, OFFSET/CHANNELS/child seen
        self.stack: list[list] = []
        self.pending: tuple[int, int] | None = None  # node declared at a line, waiting for its "{"
        self.closed = False  # the ROOT block has been closed

    def error(self, lineno: int, message: str) -> NoReturn:
        raise MocapFileError(f"{self.path}:{lineno}: {message}")

    def label(self, node: int) -> str:
        if node >= 0:
            return f"{'ROOT' if self.parents[node] < 0 else 'JOINT'} {_quote(self.names[node])}"
        return f"End Site of {_quote(self.names[self.end_parents[~node]])}"

    def statement(self, lineno: int, tokens: list[bytes]) -> bool:
        """Apply one HIERARCHY line; return True at MOTION."""
        key = tokens[0].upper()
        if self.pending is not None:
            node, decl = self.pending
            if key != b"{" or len(tokens) != 1:
                self.error(
                    lineno, f"{self.label(node)} (line {decl}) must be followed by '{{', got {_quote(tokens[0])}"
                )
            self.stack.append([node, decl, False, False, False])
            self.pending = None
            return False
        if self.closed and key not in (b"MOTION", b"ROOT"):
            self.error(lineno, f"unexpected {_quote(tokens[0])} after the ROOT's closing brace (expected MOTION)")
        handler = self._HANDLERS.get(key)
        if handler is None or (key == b"END" and (len(tokens) != 2 or tokens[1].upper() != b"SITE")):
            self.error(lineno, f"unexpected {_quote(tokens[0])} in HIERARCHY")
        return handler(self, lineno, tokens)

    def _open(self, lineno: int, tokens: list[bytes]) -> bool:
        self.error(lineno, "'{' without a ROOT, JOINT or End Site before it")

    def _close(self, lineno: int, tokens: list[bytes]) -> bool:
        if len(tokens) != 1:
            self.error(lineno, f"unexpected {_quote(tokens[1])} after '}}'")
        if not self.stack:
            self.error(lineno, "unmatched '}'")
        node, decl, has_offset, _, _ = self.stack.pop()
        if not has_offset:
            self.error(lineno, f"{self.label(node)} (line {decl}) has no OFFSET")
        self.closed = not self.stack
        return False

    def _top(self, lineno: int, what: str, joint_only: bool) -> list:
        if not self.stack:
            self.error(lineno, f"{what} outside any joint")
        top = self.stack[-1]
        if joint_only and top[0] < 0:
            self.error(lineno, f"{what} inside an End Site")
        return top

    def _first(self, lineno: int, what: str, joint_only: bool, seen: int) -> list:
        """``_top`` for a statement a node holds once (``seen``: index of its flag in the stack entry), before
        its first child."""
        top = self._top(lineno, what, joint_only)
        if top[seen]:
            self.error(lineno, f"second {what} in {self.label(top[0])}")
        if top[4]:
            self.error(lineno, f"{what} of {self.label(top[0])} after its first child")
        return top

    def _offset(self, lineno: int, tokens: list[bytes]) -> bool:
        top = self._first(lineno, "OFFSET", joint_only=False, seen=2)
        if len(tokens) != 4:
            self.error(lineno, f"OFFSET needs 3 numbers, got {len(tokens) - 1}")
        values = [float(t) for t in tokens[1:]] if _FLOAT3_RE.fullmatch(b" ".join(tokens[1:])) else []
        if not (values and math.isfinite(sum(values))):  # name the bad value
            values = [_number(self.path, lineno, t, "OFFSET values are not numbers") for t in tokens[1:]]
        node = top[0]
        (self.offsets[node] if node >= 0 else self.end_sites[~node])[:] = values
        top[2] = True
        return False

    def _channels(self, lineno: int, tokens: list[bytes]) -> bool:
        top = self._first(lineno, "CHANNELS", joint_only=True, seen=3)
        if len(tokens) < 2 or not _INT_RE.fullmatch(tokens[1]):
            self.error(lineno, f"CHANNELS needs a count, got {_quote(tokens[1]) if len(tokens) > 1 else 'nothing'}")
        count = int(tokens[1])
        if count != len(tokens) - 2:
            self.error(lineno, f"CHANNELS says {count} but lists {len(tokens) - 2} names")
        chans = tuple(_CHANNEL_BY_BYTES.get(t, "") for t in tokens[2:])
        if "" in chans:
            bad = tokens[2 + chans.index("")]
            self.error(lineno, f"unknown channel name {_quote(bad)}; expected one of {', '.join(CHANNEL_NAMES)}")
        if len(set(chans)) != count:
            self.error(lineno, "a channel is listed twice")
        self.channels[top[0]] = chans
        top[3] = True
        return False

    def _joint(self, lineno: int, tokens: list[bytes]) -> bool:
        root = tokens[0].upper() == b"ROOT"
        if root and self.stack:
            self.error(lineno, "ROOT inside a joint (children are declared with JOINT)")
        if root and self.names:
            self.error(lineno, "more than one ROOT is not supported")
        if not root:
            top = self._top(lineno, "JOINT", joint_only=True)
            if not top[2]:
                self.error(lineno, f"{self.label(top[0])} (line {top[1]}) has no OFFSET before its first child")
            top[4] = True
        name = _decode_name(b" ".join(tokens[1:]))
        problem = _name_problem(name)
        if problem:
            self.error(lineno, f"{tokens[0].decode()} name {_quote(name)} {problem}")
        if name in self.name_line:
            self.error(lineno, f"joint name {_quote(name)} is already used at line {self.name_line[name]}")
        self.name_line[name] = lineno
        self.names.append(name)
        self.parents.append(-1 if root else self.stack[-1][0])
        self.offsets.append([0.0, 0.0, 0.0])
        self.channels.append(())
        self.pending = (len(self.names) - 1, lineno)
        return False

    def _end_site(self, lineno: int, tokens: list[bytes]) -> bool:
        top = self._top(lineno, "End Site", joint_only=True)
        if not top[2]:
            self.error(lineno, f"{self.label(top[0])} (line {top[1]}) has no OFFSET before its End Site")
        top[4] = True
        self.end_parents.append(top[0])
        self.end_sites.append([0.0, 0.0, 0.0])
        self.pending = (~(len(self.end_sites) - 1), lineno)
        return False

    def _motion(self, lineno: int, tokens: list[bytes]) -> bool:
        if len(tokens) != 1:
            self.error(lineno, f"unexpected {_quote(tokens[1])} after MOTION")
        if self.stack:
            self.error(lineno, f"MOTION before the hierarchy's braces are closed ({len(self.stack)} open)")
        if not self.names:
            self.error(lineno, "hierarchy has no joints")
        return True

    def _hierarchy(self, lineno: int, tokens: list[bytes]) -> bool:
        self.error(lineno, "second HIERARCHY keyword")

    _HANDLERS = {
        b"{": _open,
        b"}": _close,
        b"OFFSET": _offset,
        b"CHANNELS": _channels,
        b"ROOT": _joint,
        b"JOINT": _joint,
        b"END": _end_site,
        b"MOTION": _motion,
        b"HIERARCHY": _hierarchy,
    }

    def skeleton(self) -> Skeleton:
        return Skeleton(
            names=tuple(self.names),
            parents=tuple(self.parents),
            offsets=np.array(self.offsets, dtype=np.float64).reshape(-1, 3),
            channels=tuple(self.channels),
            end_sites=np.array(self.end_sites, dtype=np.float64).reshape(-1, 3),
            end_parents=tuple(self.end_parents),
        )


class _Lines:
    """Line-by-line cursor over the head of a BVH file (bytes), tracking the line number."""

    def __init__(self, path: Path, raw: bytes) -> None:
        self.path, self.raw, self.pos, self.lineno = path, raw, 0, 0

    def next_tokens(self) -> list[bytes] | None:
        """Tokens of the next non-blank line (``lineno`` is its number), or None at the end of the file."""
        raw = self.raw
        while self.pos < len(raw):
            end = raw.find(b"\n", self.pos)
            end = len(raw) if end < 0 else end
            self.lineno += 1
            if end - self.pos > _MAX_HIERARCHY_LINE:
                raise MocapFileError(
                    f"{self.path}:{self.lineno}: line of {end - self.pos:,} characters "
                    f"({_quote(raw[self.pos : self.pos + _QUOTE])}); a header line is at most {_MAX_HIERARCHY_LINE}"
                )
            tokens = raw[self.pos : end].split()
            self.pos = end + 1
            if tokens:
                return tokens
        return None

    def header(self, pattern: re.Pattern, label: str) -> bytes:
        """The value after ``label`` (e.g. ``Frames:``) on the next non-blank line."""
        tokens = self.next_tokens()
        if tokens is None:
            raise MocapFileError(f"{self.path}:{self.lineno}: file ends before '{label}' (truncated MOTION section)")
        match = pattern.fullmatch(b" ".join(tokens))
        if match is None:
            raise MocapFileError(f"{self.path}:{self.lineno}: expected '{label}', got {_quote(b' '.join(tokens))}")
        return match.group(1).strip()


def _parse_hierarchy(path: Path, lines: _Lines) -> _Hierarchy:
    """Read HIERARCHY up to and including the MOTION line (the line loop of ``_Lines.next_tokens``, inlined)."""
    tokens = lines.next_tokens()
    if tokens is None or tokens[0].upper() != b"HIERARCHY" or len(tokens) != 1:
        raise MocapFileError(f"{path}:{max(lines.lineno, 1)}: expected 'HIERARCHY' at the start of a BVH file")
    hier = _Hierarchy(path)
    raw, pos, lineno, size = lines.raw, lines.pos, lines.lineno, len(lines.raw)
    while pos < size:
        end = raw.find(b"\n", pos)
        end = size if end < 0 else end
        lineno += 1
        if end - pos > _MAX_HIERARCHY_LINE:
            lines.pos, lines.lineno = pos, lineno - 1
            lines.next_tokens()  # raises, naming the line
        tokens = raw[pos:end].split()
        pos = end + 1
        if tokens and hier.statement(lineno, tokens):
            lines.pos, lines.lineno = pos, lineno
            return hier
    raise MocapFileError(f"{path}:{lineno}: file ends before the MOTION section (truncated hierarchy?)")


def _read_hierarchy(path: Path, lines: _Lines) -> tuple[Skeleton, float]:
    """The skeleton (with its guessed unit) and that unit, from the cache when these exact HIERARCHY bytes were
    read before.

    A corpus shares a few skeletons (3 distinct hierarchies among 300 bandai2 files), so the parse result is
    kept by content for the last ``_HIERARCHY_CACHE_SIZE`` hierarchies; the cached skeleton's arrays are
    read-only, as the skeleton is shared by the motions read with it.
    """
    motion = _MOTION_LINE_RE.search(lines.raw)
    key = lines.raw[: motion.end()] if motion else None
    hit = _HIERARCHY_CACHE.get(key) if key else None
    if hit is None:
        skeleton = _parse_hierarchy(path, lines).skeleton()
        skeleton.offsets.flags.writeable = skeleton.end_sites.flags.writeable = False
        unit = guess_cm_per_unit(skeleton)
        skeleton = dataclasses.replace(skeleton, cm_per_unit=unit)
        hit = skeleton, unit, lines.pos, lines.lineno
        if key is not None and lines.pos == motion.end() + 1:
            with _HIERARCHY_LOCK:  # readers may share the cache across threads
                while len(_HIERARCHY_CACHE) >= _HIERARCHY_CACHE_SIZE:
                    del _HIERARCHY_CACHE[next(iter(_HIERARCHY_CACHE))]
                _HIERARCHY_CACHE[key] = hit
    skeleton, unit, lines.pos, lines.lineno = hit
    return skeleton, unit


def _whitespace(a: np.ndarray) -> np.ndarray:
    """Boolean mask of ASCII whitespace in a uint8 array."""
    return (a == 32) | ((a >= 9) & (a <= 13))


def _tokens_per_line(a: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Number of tokens on each line of the uint8 text ``a`` whose token start offsets are ``starts``."""
    edges = np.concatenate(([0], np.flatnonzero(a == 10) + 1, [a.size]))
    return np.diff(np.searchsorted(starts, edges))


def _token_start_mask(a: np.ndarray) -> np.ndarray:
    """Boolean mask of the bytes of the uint8 text ``a`` that start a whitespace-separated token."""
    ws = _whitespace(a)
    start = ~ws
    start[1:] &= ws[:-1]
    return start


def _parse_general(body: bytes, n_channels: int) -> np.ndarray | None:
    """``[T, n_channels]`` frames through ``numpy.loadtxt``, or None when the text does not parse."""
    if not body.isascii() or any(separator in body for separator in _INFO_SEPARATORS):
        return None  # loadtxt would take these for whitespace; other control characters fail in loadtxt
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # loadtxt warns on input with no data; the caller checks that
            data = np.loadtxt(io.StringIO(body.decode("ascii")), dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None
    return data if data.shape[1] == n_channels else None


def _count_tokens(line: bytes) -> int:
    """Whitespace-separated tokens in ``line``, without making them (memory ~3x the line, not ~25x)."""
    if len(line) < _BLOCK:
        return len(line.split())
    return int(np.count_nonzero(_token_start_mask(np.frombuffer(line, np.uint8))))


def _check_long_lines(path: Path, body: bytes, first_line: int, n_channels: int) -> None:
    """Raise for a MOTION line far too long for its frame (over 64 bytes a value) without the right count.

    Runs before the number parsers so that one huge line (a file whose newlines were lost) costs a few times
    its size in memory, not one float and index per token.
    """
    a = np.frombuffer(body, np.uint8)
    ends = np.concatenate((np.flatnonzero(a == 10), [a.size]))
    starts = np.concatenate(([0], ends[:-1] + 1))
    for i in np.flatnonzero(ends - starts > 64 * n_channels + 1024):
        count = _count_tokens(body[starts[i] : ends[i]])
        if count not in (0, n_channels):
            raise MocapFileError(f"{path}:{first_line + i}: expected {n_channels} values per frame, got {count:,}")


def _line_problem(line: bytes, n_channels: int) -> str | None:
    """What is wrong with one MOTION line (bytes), or None; memory bounded for very long lines."""
    count = _count_tokens(line)
    if count == 0:
        return None
    if count != n_channels:
        return f"expected {n_channels} values per frame, got {count}"
    for token in line.split():
        if not (_FLOAT_RE.fullmatch(token) or _NON_FINITE_RE.fullmatch(token)):
            return f"{_quote(token)} is not a number"
    bad = _BAD_BYTE_RE.search(line)
    if bad:
        return f"control character {_quote(bad.group())} in MOTION data"
    return None


def _diagnose_frames(path: Path, body: bytes, first_line: int, n_channels: int) -> NoReturn:
    """Slow path: find the first bad MOTION line, block by block, and raise an error naming it."""
    start, lineno = 0, first_line
    while start < len(body):
        end = body.find(b"\n", start + _BLOCK)
        end = len(body) if end < 0 else end + 1
        block = body[start:end]
        # a block holding a line over _BLOCK bytes is checked in Python (token counts without splitting it)
        if len(block) > 2 * _BLOCK or _parse_general(block, n_channels) is None:
            offset = start
            for k, line in enumerate(block.split(b"\n")):
                problem = _line_problem(line, n_channels)
                offset += len(line) + 1
                if problem:
                    last = _NON_SPACE_RE.search(body, offset) is None
                    hint = " (truncated file?)" if _NUMBERS_RE.fullmatch(line) else " (text after the last frame?)"
                    raise MocapFileError(f"{path}:{lineno + k}: {problem}" + (hint if last else ""))
            if len(block) <= 2 * _BLOCK:
                raise MocapFileError(f"{path}:{lineno}: MOTION data could not be parsed")
        lineno += block.count(b"\n")
        start = end
    raise MocapFileError(f"{path}:{first_line}: MOTION data could not be parsed")


def _frame_line(body: bytes, first_line: int, row: int) -> int:
    """Line number of frame ``row`` (0-based) of the MOTION text ``body`` starting at line ``first_line``."""
    a = np.frombuffer(body, np.uint8)
    counts = _tokens_per_line(a, np.flatnonzero(_token_start_mask(a)))
    return first_line + int(np.flatnonzero(counts > 0)[row])


def unwrap_rotations(data: np.ndarray, rotation: np.ndarray) -> None:
    """Unwrap (in place) the rotation columns of ``data [T, C]`` that jump by more than 180° between frames.

    Same values as ``np.unwrap(period=360)`` on every rotation column: a column without such a jump is left
    as it is, which is what ``np.unwrap`` does to it.
    """
    if data.shape[0] < 2:
        return
    cols = np.flatnonzero(rotation & (data.max(axis=0) - data.min(axis=0) > 180.0))  # a jump is possible
    if cols.size:
        cols = cols[np.abs(np.diff(data[:, cols], axis=0)).max(axis=0) > 180.0]
    if cols.size:
        data[:, cols] = np.unwrap(data[:, cols], period=360.0, axis=0)


def guess_cm_per_unit(skeleton: Skeleton) -> float:
    """Centimetres per skeleton unit, guessed so the body is closest to 170 cm tall (log scale).

    Height is estimated as the sum of the two longest bone chains hanging from the hips (leg + spine/arm),
    which does not depend on how the rest pose is oriented. Linear in the joint count.
    """
    n = skeleton.n_joints
    length = np.linalg.norm(skeleton.offsets, axis=1)
    reach = np.zeros(n)  # longest chain length below each joint
    if skeleton.end_parents:
        np.maximum.at(reach, np.asarray(skeleton.end_parents), np.linalg.norm(skeleton.end_sites, axis=1))
    order: list[int] = []  # breadth-first from the root(s): parents before children
    queue = deque(j for j, p in enumerate(skeleton.parents) if p < 0)
    while queue:
        j = queue.popleft()
        order.append(j)
        queue.extend(skeleton.children[j])
    for j in reversed(order):
        p = skeleton.parents[j]
        if p >= 0:
            reach[p] = max(reach[p], reach[j] + length[j])
    hips = skeleton.context_joints[-1]
    branches = sorted((reach[c] + length[c] for c in skeleton.children[hips]), reverse=True)
    height = sum(branches[:2]) or 1.0
    units = np.array(list(_UNIT_CANDIDATES.values()))
    return float(units[np.argmin(np.abs(np.log(height * units / 170.0)))])


def read_bvh(
    path: str | os.PathLike, cm_per_unit: float | None = None, unwrap: bool = True, max_bytes: int = MAX_BVH_BYTES
) -> Motion:
    """Read a BVH file (``.bvh``, or gzip-compressed ``.bvh.gz``).

    Parameters
    ----------
    path : file to read.
    cm_per_unit : centimetres per length unit of the file; ``None`` guesses it from the rest pose's height.
    unwrap : unwrap rotation channels along time (period 360°).
    max_bytes : refuse files larger than this once decompressed (default 1 GiB).

    Returns
    -------
    Motion with ``channels [T, C]`` in degrees / file units and ``fps = 1 / Frame Time``.

    Raises
    ------
    MocapFileError naming the file and line for any syntax or value error.
    """
    path = Path(path)
    return _parse(_read_bytes(path, max_bytes), path, cm_per_unit, unwrap)


def parse_bvh(
    text: str | bytes, path: str | os.PathLike = "<text>", cm_per_unit: float | None = None, unwrap: bool = True
) -> Motion:
    """Parse BVH ``text``; ``path`` is used for the clip name and in error messages (see ``read_bvh``)."""
    path = Path(path)
    raw = text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass")
    nul = raw.find(b"\0")
    if nul >= 0:
        _binary_error(path, [raw], nul)
    return _parse(raw, path, cm_per_unit, unwrap)


def _parse(raw: bytes, path: Path, cm_per_unit: float | None, unwrap: bool) -> Motion:
    raw = raw.removeprefix(_BOM)
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    lines = _Lines(path, raw)
    skeleton, guessed_unit = _read_hierarchy(path, lines)
    value = lines.header(_FRAMES_RE, "Frames:")
    if not _INT_RE.fullmatch(value):
        raise MocapFileError(f"{path}:{lines.lineno}: 'Frames:' must be an integer, got {_quote(value)}")
    n_frames, frames_line = int(value), lines.lineno
    value = lines.header(_FRAME_TIME_RE, "Frame Time:")
    frame_time = _number(path, lines.lineno, value, "'Frame Time:'")
    low, high = _FRAME_TIME_RANGE
    if not low <= frame_time <= high:
        raise MocapFileError(
            f"{path}:{lines.lineno}: 'Frame Time:' must be between {low:g} and {high:g} seconds, got {frame_time:g}"
        )
    if n_frames == 0:
        raise MocapFileError(f"{path}:{frames_line}: empty MOTION section (Frames: 0)")
    start, first_line = lines.pos, lines.lineno + 1
    if _NON_SPACE_RE.search(raw, start) is None:
        raise MocapFileError(f"{path}:{lines.lineno}: empty MOTION section: no frame lines after 'Frame Time:'")
    n_ch = skeleton.n_channels
    if n_ch == 0:
        raise MocapFileError(f"{path}:{frames_line}: the hierarchy declares no CHANNELS, yet frames follow")
    if len(raw) - start > (raw.count(b"\n", start) + 1) * (64 * n_ch + 1024):  # some line is far too long
        _check_long_lines(path, raw[start:], first_line, n_ch)
    data = parse_frames(raw, n_ch, start)
    if data is None:
        body = raw[start:]
        data = _parse_general(body, n_ch)
        if data is None:
            _diagnose_frames(path, body, first_line, n_ch)
        bad = ~np.isfinite(data)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise MocapFileError(
                f"{path}:{_frame_line(body, first_line, int(row))}: frame {row + 1} channel "
                f"{skeleton.channel_labels[col]} is {data[row, col]}"
            )
    if data.shape[0] != n_frames:
        raise MocapFileError(
            f"{path}:{frames_line}: 'Frames: {n_frames}' but the MOTION section has {data.shape[0]} frame lines"
            + (" (truncated file?)" if data.shape[0] < n_frames else "")
        )
    if cm_per_unit is None:
        cm_per_unit = guessed_unit
    if cm_per_unit != skeleton.cm_per_unit:
        skeleton = dataclasses.replace(skeleton, cm_per_unit=float(cm_per_unit))
    if unwrap:
        unwrap_rotations(data, skeleton.rotation_mask)
    name = path.name.removesuffix(".gz").removesuffix(".bvh")
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < _FPS_ROUNDING * fps:  # "Frame Time: 0.0333333" means 30 fps
        fps = float(round(fps))
    header = _MOTION_LINE_RE.search(raw)
    try:  # the names' encoding, written back as read (``_decode_name``)
        raw[: header.start() if header else len(raw)].decode("utf-8")
        encoding = "utf-8"
    except UnicodeDecodeError:
        encoding = "latin-1"
    return Motion(skeleton, data, fps, name=name, frame_time=frame_time, encoding=encoding)


def _writable_problem(motion: Motion) -> str | None:
    """Why ``motion`` cannot be written as a BVH file that reads back as itself, or None."""
    sk = motion.skeleton
    roots = [j for j, p in enumerate(sk.parents) if p < 0]
    if roots != [0]:
        return f"a BVH file has exactly one root, joint 0; this skeleton's roots are {roots[:5]}"
    if any(not 0 <= p < sk.n_joints for p in sk.parents[1:]):
        return "a parent index is out of range"
    seen: dict[str, int] = {}
    for j, name in enumerate(sk.names):
        problem = _name_problem(name)
        if problem:
            return f"joint {j} name {_quote(name)} {problem}"
        if name in seen:
            return f"joints {seen[name]} and {j} are both named {_quote(name)}; BVH joint names must be unique"
        seen[name] = j
    for j, chans in enumerate(sk.channels):
        if len(set(chans)) != len(chans) or not set(chans) <= set(CHANNEL_NAMES):
            return f"joint {_quote(sk.names[j])} has invalid channels {chans}"
    if not (np.isfinite(sk.offsets).all() and np.isfinite(sk.end_sites).all()):
        return "the skeleton has a non-finite OFFSET"
    low, high = _FRAME_TIME_RANGE
    if not (np.isfinite(motion.fps) and low <= 1.0 / motion.fps <= high):
        return f"fps {motion.fps} is out of range"
    if motion.n_frames == 0:
        return "the motion has no frames"
    return None


def _frame_time_text(motion: Motion) -> str:
    """``Frame Time`` as the file it was read from had it (``motion.frame_time``, shortest round-trip digits) while
    it still gives the motion's ``fps`` (within ``read_bvh``'s 0.1 % rounding), else ``1 / fps``."""
    kept = motion.frame_time
    if kept is not None and abs(1.0 / kept - motion.fps) < _FPS_ROUNDING * motion.fps:
        return np.format_float_positional(float(kept), trim="-")  # repr's digits, never an exponent
    return f"{1.0 / motion.fps:.8g}"


def format_bvh(motion: Motion, precision: int = 6) -> str:
    """BVH text for ``motion`` (hierarchy, then one line per frame).

    Joints are written depth-first from the root, iteratively; the frame columns follow that order by joint
    index, never by name. Raises ``ValueError`` for a motion that would not read back as itself (duplicate
    or malformed joint names, several roots, a cycle, non-finite offsets).
    """
    problem = _writable_problem(motion)
    if problem:
        raise ValueError(f"{motion.name or 'motion'}: cannot write as BVH: {problem}")
    sk = motion.skeleton
    ends_of: dict[int, list[int]] = {}
    for e, p in enumerate(sk.end_parents):
        ends_of.setdefault(p, []).append(e)

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.10g}" if abs(x) >= 1e-12 else "0" for x in v)

    out: list[str] = ["HIERARCHY"]
    order: list[int] = []
    stack: list[tuple[int, int, bool]] = [(0, 0, False)]  # (joint, depth, closing)
    while stack:
        j, depth, closing = stack.pop()
        tab = "\t" * depth
        if closing:
            for e in ends_of.get(j, ()):
                out.extend([f"{tab}\tEnd Site", f"{tab}\t{{", f"{tab}\t\tOFFSET {fmt(sk.end_sites[e])}", f"{tab}\t}}"])
            out.append(f"{tab}}}")
            continue
        order.append(j)
        out.extend(
            [f"{tab}{'JOINT' if depth else 'ROOT'} {sk.names[j]}", f"{tab}{{", f"{tab}\tOFFSET {fmt(sk.offsets[j])}"]
        )
        out.append(f"{tab}\tCHANNELS {' '.join([str(len(sk.channels[j])), *sk.channels[j]])}")  # 'CHANNELS 0' too
        stack.append((j, depth, True))
        stack.extend((c, depth + 1, False) for c in reversed(sk.children[j]))
    if len(order) != sk.n_joints:
        unreachable = sk.n_joints - len(order)
        raise ValueError(f"{motion.name or 'motion'}: cannot write as BVH: {unreachable} joints not below the root")
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {_frame_time_text(motion)}"]
    starts = sk.channel_offsets
    columns = np.concatenate([np.arange(starts[j], starts[j + 1]) for j in order])
    buf = io.StringIO()
    if columns.size:
        np.savetxt(buf, motion.channels[:, columns], fmt=f"%.{precision}f", delimiter=" ")
    return "\n".join(out) + "\n" + buf.getvalue()


def write_bvh(path: str | os.PathLike, motion: Motion, inputs: tuple = (), precision: int = 6) -> None:
    """Write ``motion`` as BVH (gzip-compressed when ``path`` ends in ``.gz``).

    The file appears only when complete; ``inputs`` lists source paths the output must not overwrite.
    Raises ``MocapFileError`` naming ``path`` for a motion that would not read back as itself.
    """
    if not np.isfinite(motion.channels).all():
        t, c = np.argwhere(~np.isfinite(motion.channels))[0]
        raise MocapFileError(
            f"{path}: refusing to write non-finite value at frame {t + 1}, {motion.skeleton.channel_labels[c]}"
        )
    try:
        text = format_bvh(motion, precision)
        try:
            data = text.encode(motion.encoding)  # the names as the source file had them
        except (UnicodeEncodeError, LookupError):
            data = text.encode()
    except ValueError as exc:
        raise MocapFileError(f"{path}: {exc}") from None
    with atomic_output(path, inputs) as tmp:
        if str(path).endswith(".gz"):
            with gzip.open(tmp, "wb", compresslevel=6) as fh:
                fh.write(data)
        else:
            tmp.write_bytes(data)
