"""BVH read and write for any hierarchy and channel order; ``.bvh`` and gzip-compressed ``.bvh.gz``.

The MOTION block is parsed in one vectorised call (``numpy.loadtxt``); only when that fails is the block
scanned line by line to name the offending line. Rotation channels are unwrapped along time (files that
wrap at ±180° become continuous), which leaves every rotation unchanged.
"""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError, atomic_output
from mocapnet.motion import CHANNEL_NAMES, Motion, Skeleton

# Candidate length units (cm per unit) for a skeleton whose unit is not given: the one that makes the rest
# pose closest to a 170 cm adult (log scale). CMU cgspeed's unit is 1/0.45 inch.
_UNIT_CANDIDATES = {"m": 100.0, "dm": 10.0, "cmu": 2.54 / 0.45, "inch": 2.54, "cm": 1.0, "mm": 0.1}


def _open_text(path: Path) -> str:
    if not path.exists():
        raise MocapFileError(f"{path}: no such file")
    try:
        raw = gzip.open(path, "rb").read() if path.suffix == ".gz" else path.read_bytes()
    except (OSError, EOFError) as exc:
        raise MocapFileError(f"{path}: cannot read ({exc})") from exc
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _parse_hierarchy(path: Path, lines: list[str]) -> tuple[Skeleton, int]:
    """Parse HIERARCHY; return the skeleton and the index of the MOTION line."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_sites: list[list[float]] = []
    end_parents: list[int] = []
    stack: list[int] = []  # joint index per open brace; -2 marks an End Site block
    pending: int | None = None  # node declared, waiting for its "{"
    i = 0
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines) or lines[i].strip().upper() != "HIERARCHY":
        raise MocapFileError(f"{path}:{i + 1}: expected 'HIERARCHY' at the start of a BVH file")
    i += 1
    while i < len(lines):
        tokens = lines[i].split()
        lineno = i + 1
        i += 1
        if not tokens:
            continue
        key = tokens[0].upper()
        if key == "MOTION":
            if stack or pending is not None:
                raise MocapFileError(f"{path}:{lineno}: MOTION before the hierarchy's braces are closed")
            if not names:
                raise MocapFileError(f"{path}:{lineno}: hierarchy has no joints")
            skel = Skeleton(
                names=tuple(names),
                parents=tuple(parents),
                offsets=np.array(offsets, dtype=np.float64).reshape(-1, 3),
                channels=tuple(channels),
                end_sites=np.array(end_sites, dtype=np.float64).reshape(-1, 3),
                end_parents=tuple(end_parents),
            )
            return skel, i - 1
        if key in ("ROOT", "JOINT"):
            if len(tokens) < 2:
                raise MocapFileError(f"{path}:{lineno}: {tokens[0]} without a name")
            if key == "ROOT" and names:
                raise MocapFileError(f"{path}:{lineno}: more than one ROOT is not supported")
            if key == "JOINT" and not stack:
                raise MocapFileError(f"{path}:{lineno}: JOINT outside any parent joint")
            parent = stack[-1] if stack else -1
            if parent == -2:
                raise MocapFileError(f"{path}:{lineno}: JOINT inside an End Site")
            names.append(" ".join(tokens[1:]))
            parents.append(parent)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            pending = len(names) - 1
        elif key == "END":
            if not stack or stack[-1] < 0:
                raise MocapFileError(f"{path}:{lineno}: End Site outside a joint")
            end_parents.append(stack[-1])
            end_sites.append([0.0, 0.0, 0.0])
            pending = -2
        elif key == "{":
            if pending is None:
                raise MocapFileError(f"{path}:{lineno}: '{{' without a ROOT, JOINT or End Site before it")
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                raise MocapFileError(f"{path}:{lineno}: unmatched '}}'")
            stack.pop()
        elif key == "OFFSET":
            if not stack:
                raise MocapFileError(f"{path}:{lineno}: OFFSET outside a joint")
            try:
                values = [float(t) for t in tokens[1:]]
            except ValueError:
                raise MocapFileError(
                    f"{path}:{lineno}: OFFSET values are not numbers: {lines[lineno - 1].strip()!r}"
                ) from None
            if len(values) != 3 or not np.isfinite(values).all():
                raise MocapFileError(f"{path}:{lineno}: OFFSET needs 3 finite numbers, got {tokens[1:]}")
            (end_sites if stack[-1] == -2 else offsets)[-1 if stack[-1] == -2 else stack[-1]] = values
        elif key == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise MocapFileError(f"{path}:{lineno}: CHANNELS outside a joint")
            try:
                count = int(tokens[1])
            except (IndexError, ValueError):
                raise MocapFileError(f"{path}:{lineno}: CHANNELS needs a count, got {tokens[1:]}") from None
            chans = tuple(tokens[2:])
            if len(chans) != count:
                raise MocapFileError(f"{path}:{lineno}: CHANNELS says {count} but lists {len(chans)} names")
            unknown = [c for c in chans if c not in CHANNEL_NAMES]
            if unknown:
                raise MocapFileError(
                    f"{path}:{lineno}: unknown channel name(s) {unknown}; expected {list(CHANNEL_NAMES)}"
                )
            channels[stack[-1]] = chans
        else:
            raise MocapFileError(f"{path}:{lineno}: unexpected {tokens[0]!r} in HIERARCHY")
    raise MocapFileError(f"{path}: file ends before the MOTION section (truncated hierarchy?)")


def _header_value(path: Path, lines: list[str], i: int, label: str) -> tuple[str, int]:
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise MocapFileError(f"{path}: file ends before '{label}' (truncated MOTION section)")
    text = lines[i].strip()
    if not text.lower().startswith(label.lower()):
        raise MocapFileError(f"{path}:{i + 1}: expected '{label}', got {text[:40]!r}")
    return text[len(label) :].strip(), i + 1


def _diagnose_rows(path: Path, lines: list[str], start: int, n_channels: int) -> None:
    """Slow path: find the first bad data line and raise an error naming it."""
    for k in range(start, len(lines)):
        tokens = lines[k].split()
        if not tokens:
            continue
        if len(tokens) != n_channels:
            raise MocapFileError(
                f"{path}:{k + 1}: expected {n_channels} values per frame, got {len(tokens)}"
                + (" (truncated file?)" if k == len(lines) - 1 else "")
            )
        for t in tokens:
            try:
                float(t)
            except ValueError:
                raise MocapFileError(f"{path}:{k + 1}: {t!r} is not a number") from None
    raise MocapFileError(f"{path}: MOTION data could not be parsed")


def guess_cm_per_unit(skeleton: Skeleton) -> float:
    """Centimetres per skeleton unit, guessed so the body is closest to 170 cm tall (log scale).

    Height is estimated as the sum of the two longest bone chains hanging from the hips (leg + spine/arm),
    which does not depend on how the rest pose is oriented.
    """
    n = skeleton.n_joints
    length = np.linalg.norm(skeleton.offsets, axis=1)
    reach = np.zeros(n)  # longest chain length below each joint
    for j in reversed(range(n)):
        ends = [np.linalg.norm(skeleton.end_sites[e]) for e, p in enumerate(skeleton.end_parents) if p == j]
        reach[j] = max([reach[c] + length[c] for c in skeleton.children[j]] + ends + [0.0])
    hips = skeleton.context_joints[-1]
    branches = sorted((reach[c] + length[c] for c in skeleton.children[hips]), reverse=True)
    height = sum(branches[:2]) or 1.0
    units = np.array(list(_UNIT_CANDIDATES.values()))
    return float(units[np.argmin(np.abs(np.log(height * units / 170.0)))])


def read_bvh(path: str | os.PathLike, cm_per_unit: float | None = None, unwrap: bool = True) -> Motion:
    """Read a BVH file (``.bvh`` or ``.bvh.gz``).

    Parameters
    ----------
    path : file to read.
    cm_per_unit : centimetres per length unit of the file; ``None`` guesses it from the rest pose's height.
    unwrap : unwrap rotation channels along time (period 360°).

    Returns
    -------
    Motion with ``channels [T, C]`` in degrees / file units and ``fps = 1 / Frame Time``.

    Raises
    ------
    MocapFileError naming the file and line for any syntax or value error.
    """
    path = Path(path)
    return parse_bvh(_open_text(path), path, cm_per_unit, unwrap)


def parse_bvh(
    text: str, path: str | os.PathLike = "<text>", cm_per_unit: float | None = None, unwrap: bool = True
) -> Motion:
    """Parse BVH ``text``; ``path`` is used for the clip name and in error messages (see ``read_bvh``)."""
    path = Path(path)
    lines = text.splitlines()
    skeleton, motion_line = _parse_hierarchy(path, lines)
    n_ch = skeleton.n_channels
    value, i = _header_value(path, lines, motion_line + 1, "Frames:")
    try:
        n_frames = int(value)
    except ValueError:
        raise MocapFileError(f"{path}:{i}: 'Frames:' must be an integer, got {value!r}") from None
    value, i = _header_value(path, lines, i, "Frame Time:")
    try:
        frame_time = float(value)
    except ValueError:
        raise MocapFileError(f"{path}:{i}: 'Frame Time:' must be a number, got {value!r}") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise MocapFileError(f"{path}:{i}: 'Frame Time:' must be positive, got {frame_time}")
    if n_frames <= 0:
        raise MocapFileError(f"{path}:{i - 1}: empty MOTION section (Frames: {n_frames})")
    body = [ln for ln in lines[i:] if ln.strip()]
    if not body:
        raise MocapFileError(f"{path}:{i + 1}: empty MOTION section: no frame lines after 'Frame Time:'")
    try:
        data = np.loadtxt(io.StringIO("\n".join(body)), dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        _diagnose_rows(path, lines, i, n_ch)
    if data.shape[1] != n_ch:
        _diagnose_rows(path, lines, i, n_ch)
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        line = i + 1 + int(np.flatnonzero([bool(ln.strip()) for ln in lines[i:]])[row])
        raise MocapFileError(
            f"{path}:{line}: frame {row + 1} channel {skeleton.channel_labels[col]} is {data[row, col]}"
        )
    if data.shape[0] != n_frames:
        raise MocapFileError(
            f"{path}: 'Frames: {n_frames}' but the MOTION section has {data.shape[0]} frame lines"
            + (" (truncated file?)" if data.shape[0] < n_frames else "")
        )
    if unwrap:
        rot = skeleton.rotation_mask
        data[:, rot] = np.unwrap(data[:, rot], period=360.0, axis=0)
    if cm_per_unit is None:
        cm_per_unit = guess_cm_per_unit(skeleton)
    skeleton = Skeleton(
        skeleton.names,
        skeleton.parents,
        skeleton.offsets,
        skeleton.channels,
        skeleton.end_sites,
        skeleton.end_parents,
        float(cm_per_unit),
    )
    name = path.name.removesuffix(".gz").removesuffix(".bvh")
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 1e-3 * fps:  # "Frame Time: 0.0333333" means 30 fps
        fps = float(round(fps))
    return Motion(skeleton, data, fps, name=name)


def format_bvh(motion: Motion, precision: int = 6) -> str:
    """BVH text for ``motion`` (hierarchy, then one line per frame)."""
    sk = motion.skeleton
    out: list[str] = ["HIERARCHY"]
    ends_of: dict[int, list[int]] = {}
    for e, p in enumerate(sk.end_parents):
        ends_of.setdefault(p, []).append(e)

    def fmt(v: np.ndarray) -> str:
        return " ".join(f"{x:.10g}" if abs(x) >= 1e-12 else "0" for x in v)

    def emit(j: int, depth: int) -> None:
        tab = "\t" * depth
        out.append(f"{tab}{'ROOT' if sk.parents[j] < 0 else 'JOINT'} {sk.names[j]}")
        out.append(f"{tab}{{")
        out.append(f"{tab}\tOFFSET {fmt(sk.offsets[j])}")
        if sk.channels[j]:
            out.append(f"{tab}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}")
        for c in sk.children[j]:
            emit(c, depth + 1)
        for e in ends_of.get(j, []):
            out.extend([f"{tab}\tEnd Site", f"{tab}\t{{", f"{tab}\t\tOFFSET {fmt(sk.end_sites[e])}", f"{tab}\t}}"])
        out.append(f"{tab}}}")

    emit(0, 0)
    _joint_index = {f"{'ROOT' if sk.parents[j] < 0 else 'JOINT'} {name}": j for j, name in enumerate(sk.names)}
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {1.0 / motion.fps:.8g}"]
    # The file lists channels in hierarchy (depth-first) order, whatever order the skeleton keeps joints in.
    order = [int(j) for line in out if (j := _joint_index.get(line.strip())) is not None]
    columns = np.concatenate([sk.joint_channels(j) for j in order]) if order else np.arange(0)
    buf = io.StringIO()
    np.savetxt(buf, motion.channels[:, columns], fmt=f"%.{precision}f", delimiter=" ")
    return "\n".join(out) + "\n" + buf.getvalue()


def write_bvh(path: str | os.PathLike, motion: Motion, inputs: tuple = (), precision: int = 6) -> None:
    """Write ``motion`` as BVH (gzip-compressed when ``path`` ends in ``.gz``).

    The file appears only when complete; ``inputs`` lists source paths the output must not overwrite.
    """
    if not np.isfinite(motion.channels).all():
        t, c = np.argwhere(~np.isfinite(motion.channels))[0]
        raise MocapFileError(
            f"{path}: refusing to write non-finite value at frame {t + 1}, {motion.skeleton.channel_labels[c]}"
        )
    data = format_bvh(motion, precision).encode()
    with atomic_output(path, inputs) as tmp:
        if str(path).endswith(".gz"):
            with gzip.open(tmp, "wb", compresslevel=6) as fh:
                fh.write(data)
        else:
            tmp.write_bytes(data)
