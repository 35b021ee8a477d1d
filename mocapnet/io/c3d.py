"""C3D marker data: ``read_c3d(path) -> Markers`` and ``write_c3d(path, markers, source=...)``.

Reading: the file's header and parameter section are checked first (``c3d_raw``: a damaged section or a data
block shorter than the header says is refused at once); the data are then read with ezc3d, or, for files
ezc3d refuses (MIPS/SGI processor, PhoeniX's float ``ANALOG:OFFSET``), with the PyPI ``c3d`` package.
``Markers.reader`` says which. A sample is missing when any coordinate is NaN, when all three are exactly
zero, or when its residual is negative (the C3D convention). Positions are converted to centimetres from
``POINT:UNITS``.

Writing with ``source=``: the source file's bytes are copied and only the filled samples are replaced, so
every point (model outputs included), residual, analog channel, event, parameter group, the header's first
frame and the point scale stay exactly as they were; filled samples get residual 0 ("computed, not
measured"). Without ``source`` a new file holds the markers only.
"""

from __future__ import annotations

import os
import re
import tempfile
import warnings
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError, atomic_output, check_output_path
from mocapnet.io.c3d_raw import C3DLayout, cut_to_present, decode_points, patch_points, read_layout
from mocapnet.motion import Markers

_UNIT_TO_CM = {"mm": 0.1, "cm": 1.0, "m": 100.0, "dm": 10.0, "in": 2.54, "inch": 2.54}
# POINT groups that hold model outputs (joint angles, forces, …) rather than markers.
_MODEL_OUTPUT_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS", "MODELED_MARKERS")
# Plug-in-Gait virtual points: segment code + Origin/Anterior/Lateral/Proximal axis point (PELO, LFEA, …).
_PIG_VIRTUAL = re.compile(r"^(PEL|[LR](FE|TI|FO|TO|CL|HU|RA|HN)|TRX|HED|CSP)[OALP]$|^CENTRE", re.IGNORECASE)
READERS = ("ezc3d", "c3d")


@dataclass(frozen=True, eq=False)
class C3DMarkers(Markers):
    """``Markers`` read from a C3D file; ``reader`` says what read it: ``"ezc3d"``, or ``"c3d"`` (the PyPI
    package, for the files ezc3d refuses); ``point_index [M]`` is each marker's point index in the file
    (kept by ``select``), which tells apart markers that share a label; ``first_frame`` is the file's number
    for its first frame (header word 4; Vicon trials often start well above 1)."""

    reader: str = ""
    point_index: tuple[int, ...] = ()
    first_frame: int = 1

    def select(self, indices: np.ndarray | list[int]) -> C3DMarkers:
        """The markers ``indices``, keeping each one's point index in the file."""
        picked = super().select(indices)
        if len(self.point_index) == self.n_markers:
            picked = replace(picked, point_index=tuple(self.point_index[int(i)] for i in np.asarray(indices)))
        return picked


class TruncatedC3DWarning(UserWarning):
    """A C3D file's data block holds fewer frames than its header says; the frames present were read."""


class C3DRebuiltWarning(UserWarning):
    """A C3D file could not be edited in place; the output is a new file with its points and analogs."""


@dataclass(frozen=True)
class C3DContent:
    """Every point of one C3D file as read, before markers are picked.

    ``xyz [T, P, 3]`` in the file's units (``units``), ``residuals [T, P]`` (negative = invalid), ``labels``
    of all ``P`` points in file order, ``rate`` in Hz, ``analogs [C, N]`` (``N`` = T × samples per frame,
    offset and scale applied), ``reader`` one of ``READERS``.
    """

    path: Path
    reader: str
    layout: C3DLayout
    labels: tuple[str, ...]
    xyz: np.ndarray
    residuals: np.ndarray
    rate: float
    units: str
    analogs: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.xyz.shape[0]

    @cached_property
    def visible(self) -> np.ndarray:
        """``[T, P]`` bool: finite, not exactly (0, 0, 0), residual not negative."""
        xyz = self.xyz
        return np.isfinite(xyz).all(axis=2) & ~(xyz == 0).all(axis=2) & (self.residuals >= 0)

    def marker_indices(self) -> np.ndarray:
        """File indices of the physical markers: every point except model outputs listed under
        ``POINT:ANGLES/FORCES/MOMENTS/POWERS/SCALARS/REACTIONS/MODELED_MARKERS``, Plug-in-Gait virtual axis
        points (``PELO``, ``LFEA``, …, ``Centre*``) and unlabelled ``*N`` points."""
        model = {s for g in _MODEL_OUTPUT_GROUPS for s in self.layout.strings("POINT", g)}
        return np.array(
            [
                i
                for i, lab in enumerate(self.labels)
                if lab not in model
                and not lab.rsplit(":", 1)[-1].startswith("*")
                and not _PIG_VIRTUAL.match(lab.rsplit(":", 1)[-1])
            ],
            dtype=int,
        )


def _point_labels(layout: C3DLayout, n_points: int, group: str = "POINT") -> tuple[str, ...]:
    """``LABELS`` then ``LABELS2``, ``LABELS3``, … (over 255 entries) of ``group``, padded to ``n_points``."""
    labels = list(layout.strings(group, "LABELS"))
    k = 2
    while (group, f"LABELS{k}") in layout.parameters:
        labels += layout.strings(group, f"LABELS{k}")
        k += 1
    labels += [f"{group.lower()}{i}" for i in range(len(labels), n_points)]
    return tuple(labels[:n_points])


def _read_ezc3d(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``xyz [T, P, 3]``, ``residuals [T, P]`` and ``analogs [C, N]`` (offset and scale applied)."""
    import ezc3d

    # Never ignore_bad_formatting: on some broken files it crashes the whole process (segfault).
    c3d = ezc3d.c3d(str(path), extract_forceplat_data=False)
    points = np.asarray(c3d["data"]["points"], dtype=np.float64)  # [4, P, T]
    residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)  # [1, P, T]
    analogs = np.asarray(c3d["data"]["analogs"], dtype=np.float64)  # [1, C, N]
    return points[:3].transpose(2, 1, 0), residuals[0].T, analogs.reshape(analogs.shape[-2:])


def _read_c3d_package(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As ``_read_ezc3d``, through the PyPI ``c3d`` package."""
    import c3d

    with warnings.catch_warnings(), open(path, "rb") as fh:
        warnings.simplefilter("ignore")
        frames = [(points[:, :4], analog) for _, points, analog in c3d.Reader(fh).read_frames()]
    if not frames:
        return np.zeros((0, 0, 3)), np.zeros((0, 0)), np.zeros((0, 0))
    data = np.stack([p for p, _ in frames]).astype(np.float64)  # [T, P, 4]: x, y, z, residual (-1 = invalid)
    analogs = np.concatenate([a for _, a in frames], axis=1).astype(np.float64)  # [C, N]
    return data[..., :3], data[..., 3], analogs


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def load_c3d(path: str | os.PathLike, *, allow_truncated: bool = False) -> C3DContent:
    """Read every point of a C3D file: ezc3d first, the PyPI ``c3d`` package for files ezc3d refuses.

    A data block shorter than the header says raises ``MocapFileError`` naming both frame counts, or with
    ``allow_truncated`` warns (``TruncatedC3DWarning``) and reads the frames present.
    """
    path = Path(path)
    layout = read_layout(path)
    if layout.truncated:
        msg = (
            f"{path}: truncated C3D file: the header says {layout.frames} frames but the data block holds "
            f"{layout.frames_present}"
        )
        if not allow_truncated or layout.frames_present == 0:
            raise MocapFileError(msg + ("" if allow_truncated else " (--allow-truncated reads the frames present)"))
        warnings.warn(msg + "; reading those", TruncatedC3DWarning, stacklevel=3)
    try:
        xyz, residuals, analogs = _read_ezc3d(path)
        reader = "ezc3d"
    except Exception as exc:  # ezc3d raises RuntimeError, OSError, ValueError, IndexError, …
        try:
            xyz, residuals, analogs = _read_c3d_package(path)
            reader = "c3d"
        except Exception as exc2:  # a third-party parser: anything it raises means it cannot read the file
            raise MocapFileError(
                f"{path}: ezc3d cannot read this C3D file: {_one_line(exc)}; nor can the c3d package: {_one_line(exc2)}"
            ) from exc
    present = min(xyz.shape[0], layout.frames_present)
    rate = layout.number("POINT", "RATE") or layout.header_rate
    units = (layout.strings("POINT", "UNITS") or ["mm"])[0].strip().lower() or "mm"
    per_frame = analogs.shape[1] // max(xyz.shape[0], 1)
    return C3DContent(
        path, reader, layout, _point_labels(layout, xyz.shape[1]), xyz[:present], residuals[:present], rate, units,
        analogs[:, : present * per_frame],
    )  # fmt: skip


def read_c3d(path: str | os.PathLike, markers_only: bool = True, *, allow_truncated: bool = False) -> C3DMarkers:
    """Read marker trajectories from a C3D file.

    Parameters
    ----------
    path : the ``.c3d`` file.
    markers_only : drop model outputs listed under ``POINT:ANGLES/FORCES/MOMENTS/POWERS/SCALARS/
        MODELED_MARKERS``, Plug-in-Gait virtual axis points (``PELO``, ``LFEA``, …, ``Centre*``) and the
        unlabelled ``*N`` points, keeping physical markers only.
    allow_truncated : read the complete frames of a file whose data block is shorter than its header says
        (with a ``TruncatedC3DWarning``) instead of raising.

    Returns
    -------
    C3DMarkers (a ``Markers``) with ``points [T, M, 3]`` in cm (NaN where missing), ``visible [T, M]``,
    labels, rate in Hz and ``reader`` (``"ezc3d"`` or ``"c3d"``, the PyPI package used for files ezc3d refuses).

    Raises
    ------
    MocapFileError naming the file when no reader accepts it, it is truncated, or it holds no usable marker
    data.
    """
    path = Path(path)
    content = load_c3d(path, allow_truncated=allow_truncated)
    if content.xyz.shape[1] == 0 or content.n_frames == 0:
        raise MocapFileError(f"{path}: no POINT data (0 markers or 0 frames)")
    if not content.rate > 0:
        raise MocapFileError(f"{path}: point rate is {content.rate}, expected a positive number of Hz")
    if content.units not in _UNIT_TO_CM:
        raise MocapFileError(f"{path}: unknown POINT:UNITS {content.units!r} (expected one of {sorted(_UNIT_TO_CM)})")
    keep = content.marker_indices() if markers_only else np.arange(len(content.labels))
    if keep.size == 0:
        raise MocapFileError(f"{path}: all {len(content.labels)} points are model outputs or unlabelled; no markers")
    visible = content.visible[:, keep]
    if not visible.any():
        raise MocapFileError(
            f"{path}: every marker sample is missing (NaN, exactly zero or negative residual): no usable data"
        )
    xyz = content.xyz[:, keep] * _UNIT_TO_CM[content.units]
    labels = [content.labels[i] for i in keep]
    return C3DMarkers(
        xyz, visible, labels, content.rate, path.name, content.reader, tuple(int(i) for i in keep),
        int(content.layout.first_frame),
    )  # fmt: skip


def _match_columns(content: C3DContent, markers: Markers) -> np.ndarray:
    """The file's point index of each marker: ``C3DMarkers.point_index`` when it fits the file (same labels
    there), else by label: the k-th marker called L is the file's k-th point called L, among the physical
    markers first (as ``read_c3d`` picks them), else among all points."""
    index = getattr(markers, "point_index", ())
    if len(index) == markers.n_markers and all(
        0 <= i < len(content.labels) and content.labels[i] == lab for i, lab in zip(index, markers.labels)
    ):
        return np.array(index, dtype=int)
    for candidates in (content.marker_indices(), np.arange(len(content.labels))):
        by_label: dict[str, list[int]] = {}
        for i in candidates:
            by_label.setdefault(content.labels[i], []).append(int(i))
        seen: dict[str, int] = {}
        index = []
        for label in markers.labels:
            k = seen.get(label, 0)
            seen[label] = k + 1
            if k >= len(by_label.get(label, ())):
                break
            index.append(by_label[label][k])
        else:
            return np.array(index, dtype=int)
    missing = next(lab for lab in markers.labels if lab not in content.labels)
    raise MocapFileError(f"{content.path}: has no point labelled {missing!r} to write the filled samples into")


def _write_edited(
    path: Path, markers: Markers, inputs: tuple, source: Path, filled: np.ndarray | None, moved: np.ndarray | None
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedC3DWarning)
        content = load_c3d(source, allow_truncated=True)
    if markers.n_frames != content.n_frames:
        raise MocapFileError(
            f"{source}: holds {content.n_frames} frames but the markers to write have {markers.n_frames}"
        )
    if content.units not in _UNIT_TO_CM:
        raise MocapFileError(f"{source}: unknown POINT:UNITS {content.units!r}; cannot convert filled samples")
    index = _match_columns(content, markers)
    if filled is None:
        filled = markers.visible & ~content.visible[:, index]
    filled = np.asarray(filled)
    if filled.dtype != bool or filled.shape != markers.visible.shape:
        raise ValueError(
            f"filled must be a bool [T, M] = {markers.visible.shape} array, got {filled.dtype} {filled.shape}"
        )
    if (filled & ~markers.visible).any():
        t, m = np.argwhere(filled & ~markers.visible)[0]
        raise ValueError(
            f"{markers.name or 'markers'}: filled sample at frame {t + 1}, {markers.labels[m]} has no value"
        )
    moved = np.zeros_like(filled) if moved is None else np.asarray(moved)
    if moved.dtype != bool or moved.shape != filled.shape:
        raise ValueError(f"moved must be a bool [T, M] = {filled.shape} array, got {moved.dtype} {moved.shape}")
    wrong = moved & (filled | ~content.visible[:, index] | ~markers.visible)
    if wrong.any():
        t, m = np.argwhere(wrong)[0]
        raise ValueError(
            f"{markers.name or 'markers'}: moved sample at frame {t + 1}, {markers.labels[m]} is not a measured "
            "sample with a value (or is also filled)"
        )
    raw = source.read_bytes()
    layout = content.layout
    stored, _ = decode_points(layout, raw)
    measured = content.visible
    values = markers.points / _UNIT_TO_CM[content.units]
    if stored.shape != content.xyz.shape or not np.allclose(stored[measured], content.xyz[measured], rtol=1e-6):
        warnings.warn(
            f"{source}: cannot edit this file in place (its data block does not decode to what {content.reader} "
            f"read); {path} is a new C3D file with its points, analog channels, labels and rates only",
            C3DRebuiltWarning,
            stacklevel=3,
        )
        _write_rebuilt(path, content, values, filled, index, (*inputs, source), moved)
        return
    edited = patch_points(layout, raw, values, filled, index, markers.labels)
    if moved.any():
        edited = patch_points(layout, edited, values, moved, index, markers.labels, computed=False)
    edited = cut_to_present(layout, edited)
    with atomic_output(path, (*inputs, source)) as tmp:
        tmp.write_bytes(edited)


def _write_rebuilt(
    path: Path,
    content: C3DContent,
    values: np.ndarray,
    filled: np.ndarray,
    index: np.ndarray,
    inputs: tuple,
    moved: np.ndarray,
) -> None:
    """A new C3D file holding every point of ``content`` (``filled`` samples replaced by ``values [T, M, 3]``
    in the file's units, residual 0; ``moved`` samples replaced, residual kept), its analog channels, labels
    and rates."""
    xyz, residuals = content.xyz.copy(), content.residuals.copy()
    t, m = np.nonzero(filled | moved)
    xyz[t, index[m]] = values[t, m]
    t, m = np.nonzero(filled)
    residuals[t, index[m]] = 0.0
    invalid = residuals < 0
    xyz[invalid] = np.nan
    analogs = content.analogs
    analog_rate = content.layout.number("ANALOG", "RATE") or 0.0
    analog = {}
    if analogs.shape[0] and analog_rate > 0:
        labels = _point_labels(content.layout, analogs.shape[0], "ANALOG")
        analog = {"rate": analog_rate, "labels": labels, "data": analogs}
    residuals[invalid] = -1.0
    _write_ezc3d(path, xyz, residuals, content.labels, content.rate, content.units, inputs, analog)


def _write_ezc3d(
    path: Path,
    xyz: np.ndarray,
    residuals: np.ndarray | None,
    labels: tuple[str, ...],
    rate: float,
    units: str,
    inputs: tuple,
    analog: dict | None = None,
) -> None:
    """Write a new C3D file through ezc3d: ``xyz [T, P, 3]`` in ``units`` (NaN = missing), ``residuals
    [T, P]`` (None: ezc3d's default), ``analog`` optional ``{"rate", "labels", "data" [C, N]}``."""
    import ezc3d

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(labels)
    c3d.add_parameter("POINT", "UNITS", [units])
    pts = np.ones((4, xyz.shape[1], xyz.shape[0]))
    pts[:3] = xyz.transpose(2, 1, 0)
    c3d["data"]["points"] = pts
    if residuals is not None:
        c3d["data"]["meta_points"] = {"residuals": residuals.T[None].astype(np.float64)}
    if analog:
        c3d["parameters"]["ANALOG"]["RATE"]["value"] = [float(analog["rate"])]
        c3d["parameters"]["ANALOG"]["LABELS"]["value"] = list(analog["labels"])
        c3d["data"]["analogs"] = np.asarray(analog["data"], dtype=np.float64)[None]
    # ezc3d appends ".c3d" to any other name, so it writes in a private folder; the bytes then go through
    # the hidden .partial file beside the output.
    with tempfile.TemporaryDirectory(prefix="mocapnet-c3d-") as folder, atomic_output(path, inputs) as tmp:
        staged = Path(folder) / "out.c3d"
        c3d.write(str(staged))
        tmp.write_bytes(staged.read_bytes())


def _write_new(path: Path, markers: Markers, inputs: tuple) -> None:
    xyz = np.where(markers.visible[..., None], markers.points * 10.0, np.nan)
    _write_ezc3d(path, xyz, None, markers.labels, markers.fps, "mm", inputs)


def write_c3d(
    path: str | os.PathLike,
    markers: Markers,
    inputs: tuple = (),
    *,
    source: str | os.PathLike | None = None,
    filled: np.ndarray | None = None,
    moved: np.ndarray | None = None,
) -> None:
    """Write markers to a C3D file, atomically (a hidden ``.NAME.*.partial`` file moved into place).

    Parameters
    ----------
    path : the output ``.c3d`` file; refused (``MocapFileError``, nothing written) when empty, a directory,
        one of ``inputs`` / ``source``, or in a folder that cannot be written.
    markers : ``points [T, M, 3]`` in cm.
    inputs : source paths the output must not overwrite.
    source : the C3D file ``markers`` was read from. Given, the output is a copy of that file in which only
        the ``filled`` samples are replaced (positions converted back to the file's ``POINT:UNITS``,
        residual 0 = computed, not measured): every other point sample, residual, point (model outputs
        included), analog channel, event, parameter group and the header stay byte for byte as they were.
        ``markers`` columns are matched to the file's points by label (the k-th marker called L is the
        file's k-th point called L), so ``markers`` may be any subset of the points, in any order. In an
        integer C3D file (``POINT:SCALE`` > 0) filled positions are rounded to the scale. A truncated source
        gives a consistent file with its complete frames. Should the file's data block not decode to what the
        reader read (a layout this module does not know), a ``C3DRebuiltWarning`` says so and the output is
        a new C3D file with every point, the analog channels, labels and rates (other groups are lost).
    filled : bool ``[T, M]``, the samples to write; default: visible in ``markers`` but missing in
        ``source``. Each must have a value in ``markers``.
    moved : bool ``[T, M]`` (with ``source``), measured samples whose positions are rewritten from ``markers``
        while their residual word (residual, cameras) stays as it was — a smoother's output. Each must be
        measured in ``source`` and not ``filled``.

    Without ``source``: a new file with the markers only (positions in mm, missing samples NaN, residual -1).
    """
    check_output_path(path, (*inputs, *(() if source is None else (source,))))
    path = Path(path)
    if source is None:
        if filled is not None or moved is not None:
            raise ValueError("filled= and moved= need source=: a new C3D file has no measured samples to keep")
        _write_new(path, markers, inputs)
    else:
        _write_edited(path, markers, tuple(inputs), Path(source), filled, moved)
