"""The byte layout of a C3D file, read without ezc3d: header, parameter section, data block.

Used to refuse damaged files fast (a parameter section that does not parse, a data block shorter than the
header says) before a full reader sees them, and to edit a file in place: ``patch_points`` rewrites only the
chosen point samples of a copy of the file's bytes, so every other byte (measured samples, residuals, analog
channels, events, every parameter group, the header) stays exactly as it was.

C3D stores each 3D frame as ``POINT:USED`` groups of four words (X, Y, Z, residual/camera word) followed by
the frame's analog samples; a word is an int16 (``POINT:SCALE`` > 0, positions = value × scale) or a float32
(``POINT:SCALE`` < 0, positions as they are) in the processor's format: Intel (little-endian IEEE),
DEC (little-endian integers, VAX F-floats) or MIPS (big-endian).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError

BLOCK = 512
PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_TYPE_SIZE = {-1: 1, 1: 1, 2: 2, 4: 4}


@dataclass(frozen=True)
class Parameter:
    """One parameter: C3D type (-1 char, 1 byte, 2 int16, 4 float), dimensions, the raw data bytes and
    where they start in the file (bytes)."""

    type: int
    dims: tuple[int, ...]
    data: bytes
    offset: int


@dataclass(frozen=True)
class C3DLayout:
    """Where everything lies in one C3D file.

    ``frames`` is the count the header (or ``POINT:FRAMES``) promises; ``frames_present`` the complete frames
    the data block really holds. Offsets are in bytes from the start of the file.
    """

    path: Path
    processor: str
    parameters: dict[tuple[str, str], Parameter]
    n_points: int
    analog_words: int
    is_float: bool
    scale: float
    data_offset: int
    frames: int
    frames_present: int
    first_frame: int
    header_rate: float

    @property
    def frame_words(self) -> int:
        """Words per 3D frame: 4 per point plus the frame's analog samples."""
        return 4 * self.n_points + self.analog_words

    @property
    def word_size(self) -> int:
        return 4 if self.is_float else 2

    @property
    def truncated(self) -> bool:
        return self.frames_present < self.frames

    def strings(self, group: str, name: str) -> list[str]:
        """A char parameter as a list of stripped strings (``[]`` when absent or not text)."""
        p = self.parameters.get((group.upper(), name.upper()))
        if p is None or p.type != -1:
            return []
        width = p.dims[0] if len(p.dims) > 1 else len(p.data)
        if width == 0:
            return []
        return [_text(p.data[i : i + width]) for i in range(0, len(p.data), width)]

    def number(self, group: str, name: str) -> float | None:
        """The first value of a numeric parameter, or ``None`` when absent or empty."""
        return _number(self.parameters, self.processor, group, name)


def _decode_float32(raw: np.ndarray, processor: str) -> np.ndarray:
    """float32 values from their stored bytes (``raw`` uint8, length a multiple of 4)."""
    raw = np.ascontiguousarray(raw, dtype=np.uint8)
    if processor == "mips":
        return raw.view(">f4").astype(np.float32)
    if processor == "dec":
        # VAX F-float: 16-bit words in the other order, exponent bias 2 higher than IEEE (a factor 4).
        swapped = raw.reshape(-1, 2, 2)[:, ::-1].reshape(-1)
        return swapped.view("<f4") / np.float32(4.0)
    return raw.view("<f4").copy()


def _encode_float32(values: np.ndarray, processor: str) -> np.ndarray:
    """Stored bytes (uint8, 4 per value) of float32 ``values`` for ``processor``."""
    values = np.asarray(values, dtype=np.float32)
    if processor == "mips":
        return values.astype(">f4").view(np.uint8)
    if processor == "dec":
        ieee = (values * np.float32(4.0)).astype("<f4").view(np.uint8)
        return ieee.reshape(-1, 2, 2)[:, ::-1].reshape(-1)
    return values.astype("<f4").view(np.uint8)


def _text(raw: bytes) -> str:
    """A C3D string: up to the first NUL, surrounding blanks removed."""
    return raw.split(b"\x00", 1)[0].decode("latin-1").strip()


def _i8(byte: int) -> int:
    return byte - 256 if byte > 127 else byte


def _int16(processor: str) -> str:
    return ">i2" if processor == "mips" else "<i2"


def _number(params: dict[tuple[str, str], Parameter], processor: str, group: str, name: str) -> float | None:
    p = params.get((group.upper(), name.upper()))
    if p is None or p.type == -1 or len(p.data) < _TYPE_SIZE[p.type]:
        return None
    if p.type == 1:
        return float(np.frombuffer(p.data[:1], dtype=np.int8)[0])
    if p.type == 2:
        return float(np.frombuffer(p.data[:2], dtype=_int16(processor))[0])
    return float(_decode_float32(np.frombuffer(p.data[:4], dtype=np.uint8), processor)[0])


def _whole(value: float | None, default: int) -> int:
    """``value`` as a non-negative whole number, ``default`` when absent, not finite, negative or zero."""
    return int(value) if value is not None and np.isfinite(value) and 0 < value < 2**31 else default


def _long_frame_count(params: dict[tuple[str, str], Parameter], processor: str) -> int | None:
    """Frame count of a recording too long for the header: ``TRIAL:ACTUAL_START_FIELD`` /
    ``ACTUAL_END_FIELD`` (two 16-bit words each, low word first), else ``POINT:FRAMES`` (int16 read as
    unsigned, or float)."""
    start, end = params.get(("TRIAL", "ACTUAL_START_FIELD")), params.get(("TRIAL", "ACTUAL_END_FIELD"))
    u16 = ">u2" if processor == "mips" else "<u2"
    if start is not None and end is not None and start.type == end.type == 2 and len(start.data) == len(end.data) == 4:
        first, last = (int(w[0]) + 65536 * int(w[1]) for w in (np.frombuffer(p.data, u16) for p in (start, end)))
        if last >= first:
            return last - first + 1
    declared = params.get(("POINT", "FRAMES"))
    if declared is None or declared.type not in (2, 4) or len(declared.data) < declared.type:
        return None
    if declared.type == 2:
        return int(np.frombuffer(declared.data[:2], u16)[0])
    return _whole(float(_decode_float32(np.frombuffer(declared.data[:4], np.uint8), processor)[0]), 0) or None


def _parse_parameters(path: Path, raw: bytes, start: int, processor: str) -> dict[tuple[str, str], Parameter]:
    """Walk the parameter section from byte ``start``; raise ``MocapFileError`` at the first bad entry."""
    i16 = _int16(processor)
    groups: dict[int, str] = {}
    entries: list[tuple[int, str, Parameter]] = []
    pos = start + 4
    end = len(raw)
    section_end = min(start + max(raw[start + 2], 1) * BLOCK, end)
    while pos + 2 <= section_end:
        n_chars = abs(_i8(raw[pos]))
        gid = _i8(raw[pos + 1])
        if n_chars == 0 or gid == 0:
            break
        name_end = pos + 2 + n_chars
        if name_end + 2 > end:
            raise MocapFileError(f"{path}: parameter section is damaged (entry at byte {pos} runs past the file)")
        name = raw[pos + 2 : name_end].decode("latin-1").strip().upper()
        if not name or not all(32 <= ord(ch) < 127 for ch in name):
            raise MocapFileError(f"{path}: parameter section is damaged (unreadable name at byte {pos})")
        offset = int(np.frombuffer(raw[name_end : name_end + 2], dtype=i16)[0])
        body = name_end + 2
        desc_at = body
        if gid < 0:
            groups[-gid] = name
        else:
            if body + 2 > end:
                raise MocapFileError(f"{path}: parameter section is damaged ({name} at byte {pos} is cut off)")
            ptype = _i8(raw[body])
            if ptype not in _TYPE_SIZE:
                raise MocapFileError(f"{path}: parameter section is damaged ({name}: unknown type {ptype})")
            n_dims = raw[body + 1]
            dims = tuple(raw[body + 2 : body + 2 + n_dims])
            size = _TYPE_SIZE[ptype] * int(np.prod(dims, dtype=np.int64))
            data_at = body + 2 + n_dims
            if data_at + size > end:
                raise MocapFileError(f"{path}: parameter section is damaged ({name} holds more than the file)")
            entries.append((gid, name, Parameter(ptype, dims, bytes(raw[data_at : data_at + size]), data_at)))
            desc_at = data_at + size
        if offset == 0:
            break
        if offset < 0 or name_end + offset <= pos:
            raise MocapFileError(f"{path}: parameter section is damaged (bad offset {offset} after {name})")
        if desc_at >= end or desc_at + 1 + raw[desc_at] > name_end + offset:
            # (ezc3d 1.7.2 hangs on such a file instead of refusing it)
            what = name if gid < 0 else f"{groups.get(gid, f'GROUP{gid}')}:{name}"
            raise MocapFileError(f"{path}: parameter section is damaged ({what} runs into the next entry)")
        pos = name_end + offset
    if not groups:
        raise MocapFileError(f"{path}: parameter section holds no parameter group (no POINT data)")
    return {(groups.get(gid, f"GROUP{gid}"), name): p for gid, name, p in entries}


def read_layout(path: str | os.PathLike) -> C3DLayout:
    """Read the header and parameter section of a C3D file and size up its data block.

    Raises ``MocapFileError`` naming the file for: no file, an empty file, a file that is not C3D, an unknown
    processor type, a parameter section that does not parse, a data block that starts past the end.
    A truncated data block is not an error here: compare ``frames_present`` with ``frames``.
    """
    path = Path(path)
    if not path.exists():
        raise MocapFileError(f"{path}: no such file")
    if path.is_dir():
        raise MocapFileError(f"{path}: is a directory, not a C3D file")
    raw = path.read_bytes()
    if not raw:
        raise MocapFileError(f"{path}: file is empty")
    if len(raw) < BLOCK or raw[1] != 0x50:
        raise MocapFileError(f"{path}: not a C3D file (byte 2 of the header is not 0x50)")
    pstart = (raw[0] - 1) * BLOCK
    if raw[0] < 1 or pstart + 4 > len(raw):
        raise MocapFileError(f"{path}: parameter section (block {raw[0]}) lies outside the file")
    proc_byte = raw[pstart + 3]
    if proc_byte not in PROCESSORS:
        raise MocapFileError(f"{path}: unknown processor type {proc_byte} (expected 84 Intel, 85 DEC, 86 MIPS)")
    processor = PROCESSORS[proc_byte]
    params = _parse_parameters(path, raw, pstart, processor)
    u16 = ">u2" if processor == "mips" else "<u2"
    words = np.frombuffer(raw[:24], dtype=u16).astype(int)
    header_scale, header_rate = _decode_float32(np.frombuffer(raw[12:16] + raw[20:24], dtype=np.uint8), processor)
    scale = _number(params, processor, "POINT", "SCALE")
    scale = float(header_scale) if scale is None or scale == 0 else scale
    if not np.isfinite(scale) or scale == 0:
        raise MocapFileError(f"{path}: POINT:SCALE is {scale}, expected a non-zero number")
    n_points = _whole(_number(params, processor, "POINT", "USED"), int(words[1])) & 0xFFFF
    frames = int(words[4]) - int(words[3]) + 1
    long_count = _long_frame_count(params, processor) if words[4] == 0xFFFF else None
    data_block = int(words[8]) or _whole(_number(params, processor, "POINT", "DATA_START"), 0)
    data_offset = (data_block - 1) * BLOCK
    if data_block < 1 or data_offset > len(raw):
        raise MocapFileError(f"{path}: data block {data_block} lies outside the file ({len(raw)} bytes)")
    frames = max(frames, 0)
    analog_words = int(words[2])
    channels = _number(params, processor, "ANALOG", "USED")
    rates = _number(params, processor, "ANALOG", "RATE"), _number(params, processor, "POINT", "RATE")
    if channels is not None and all(r is not None and 0 < r < 1e7 for r in rates):
        analog_words = _whole(channels, 0) * round(rates[0] / rates[1])
    word_bytes = 4 if scale < 0 else 2
    stride = (4 * n_points + analog_words) * word_bytes
    in_block = (len(raw) - data_offset) // stride if stride else frames
    if words[4] == 0xFFFF:  # the header's 16-bit last frame overflowed: a recording of 65,535 frames or more
        frames = long_count if long_count and long_count > frames else frames
    header_points, data_bytes = int(words[1]), len(raw) - data_offset
    if header_points != n_points and stride:
        header_stride = (4 * header_points + analog_words) * word_bytes
        # the data fit the header's count and not POINT:USED's: too short for it, or a block or more left over
        fits_header = header_stride and frames * header_stride <= data_bytes < frames * header_stride + BLOCK
        if fits_header and (in_block < frames or data_bytes - frames * stride >= BLOCK):
            raise MocapFileError(
                f"{path}: the header says {header_points} points per frame and POINT:USED says {n_points}; the data "
                f"block holds {frames} frames of {header_points} points, not of {n_points}, so the file's readers "
                f"(which take POINT:USED) would decode garbage: set POINT:USED to {header_points} in the file's "
                f"software and export it again"
            )
    present = min(in_block, frames)
    return C3DLayout(
        path, processor, params, n_points, analog_words, scale < 0, abs(scale), data_offset, frames, present,
        int(words[3]), float(header_rate),
    )  # fmt: skip


def _frame_words(layout: C3DLayout, raw: bytes | bytearray) -> np.ndarray:
    """The point words of the frames present as uint8 ``[T, 4 P, word_size]``, a view into ``raw``."""
    ws, n = layout.word_size, layout.frames_present
    block = np.frombuffer(raw, dtype=np.uint8, count=n * layout.frame_words * ws, offset=layout.data_offset)
    return block.reshape(n, layout.frame_words, ws)[:, : 4 * layout.n_points]


def decode_points(layout: C3DLayout, raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Point data of the frames present: ``xyz [T, P, 3]`` in the file's units and the residual word ``[T, P]``.

    The residual word is the stored 4th word as a number (negative = invalid sample; low byte × scale =
    residual, high byte = cameras).
    """
    view = np.ascontiguousarray(_frame_words(layout, raw)).reshape(-1)
    t, p = layout.frames_present, layout.n_points
    if layout.is_float:
        words = _decode_float32(view, layout.processor).reshape(t, p, 4).astype(np.float64)
    else:
        words = view.view(_int16(layout.processor)).reshape(t, p, 4).astype(np.float64)
        words[..., :3] *= np.float32(layout.scale)
    return words[..., :3], words[..., 3]


def patch_points(
    layout: C3DLayout,
    raw: bytes,
    values: np.ndarray,
    where: np.ndarray,
    point_index: np.ndarray,
    labels: Sequence[str] = (),
    computed: bool = True,
) -> bytearray:
    """A copy of the file's bytes with the samples ``where`` replaced by ``values``, residual 0 (``computed``;
    else the residual word is left as it is: a measured sample moved, e.g. by smoothing).

    Parameters
    ----------
    values : ``[T, M, 3]`` positions in the file's units (``T`` = frames present).
    where : bool ``[T, M]``, the samples to write; every other byte of the file is left as it is.
    point_index : ``[M]`` the file's point index of each column.
    labels : ``[M]`` names of the columns, for messages.

    Residual word 0 marks a sample as computed, not measured (C3D convention; cameras none). Raises
    ``MocapFileError`` when an integer file cannot hold a value (beyond ±32767 × POINT:SCALE).
    """
    out = bytearray(raw)
    view = _frame_words(layout, out)
    frames, cols = np.nonzero(where)
    if frames.size == 0:
        return out
    points = np.asarray(point_index)[cols]
    xyz = np.asarray(values, dtype=np.float64)[frames, cols]
    if not np.isfinite(xyz).all():
        raise ValueError(f"{layout.path}: a sample to write is not finite")
    words = np.concatenate([xyz, np.zeros((xyz.shape[0], 1))], axis=1)  # [N, 4]
    n_words = 4 if computed else 3
    if layout.is_float:
        encoded = _encode_float32(words.reshape(-1), layout.processor).reshape(-1, 4, 4)[:, :n_words]
    else:
        counts = np.rint(words / np.array([layout.scale] * 3 + [1.0]))
        bad = np.flatnonzero((np.abs(counts) > 32767).any(axis=1))
        if bad.size:
            k = bad[0]
            name = labels[cols[k]] if len(labels) > cols[k] else f"point {points[k] + 1}"
            raise MocapFileError(
                f"{layout.path}: value {xyz[k].round(1).tolist()} of {name} at frame {frames[k] + 1} does "
                f"not fit this integer C3D file (range ±{32767 * layout.scale:.1f} in file units)"
            )
        encoded = counts.astype(_int16(layout.processor)).view(np.uint8).reshape(-1, 4, 2)[:, :n_words]
    view[frames[:, None], 4 * points[:, None] + np.arange(n_words)] = encoded
    return out


def cut_to_present(layout: C3DLayout, raw: bytearray) -> bytearray:
    """Make a truncated file consistent: keep only its complete frames and say so in the header's last frame
    (and ``POINT:FRAMES``). A file that is not truncated is returned as it is."""
    if not layout.truncated:
        return raw
    end = layout.data_offset + layout.frames_present * layout.frame_words * layout.word_size
    out = bytearray(raw[:end])
    u16 = ">u2" if layout.processor == "mips" else "<u2"
    last = layout.first_frame + layout.frames_present - 1
    out[8:10] = np.array([last], dtype=u16).tobytes()
    frames = layout.parameters.get(("POINT", "FRAMES"))
    if frames is not None and frames.type == 2 and len(frames.data) >= 2:
        out[frames.offset : frames.offset + 2] = np.array([layout.frames_present], dtype=u16).tobytes()
    return out
