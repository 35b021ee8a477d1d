"""C3D marker data through ezc3d: ``read_c3d(path) -> Markers`` and ``write_c3d(path, markers)``.

A sample is missing when any coordinate is NaN, when all three are exactly zero, or when its residual is
negative (the C3D convention). Positions are converted to centimetres from ``POINT:UNITS``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError, atomic_output
from mocapnet.motion import Markers

_UNIT_TO_CM = {"mm": 0.1, "cm": 1.0, "m": 100.0, "dm": 10.0, "in": 2.54, "inch": 2.54}
# POINT groups that hold model outputs (joint angles, forces, …) rather than markers.
_MODEL_OUTPUT_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS", "MODELED_MARKERS")
# Plug-in-Gait virtual points: segment code + Origin/Anterior/Lateral/Proximal axis point (PELO, LFEA, …).
_PIG_VIRTUAL = re.compile(r"^(PEL|[LR](FE|TI|FO|TO|CL|HU|RA|HN)|TRX|HED|CSP)[OALP]$|^CENTRE", re.IGNORECASE)


def _param(group: dict, name: str, default=None):
    entry = group.get(name)
    if entry is None:
        return default
    return entry.get("value", default)


def _load(path: Path):
    import ezc3d

    if not path.exists():
        raise MocapFileError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise MocapFileError(f"{path}: file is empty")
    with open(path, "rb") as fh:
        header = fh.read(512)
    if len(header) < 512 or header[1] != 0x50:
        raise MocapFileError(f"{path}: not a C3D file (byte 2 of the header is not 0x50)")
    try:
        # Never ignore_bad_formatting: on some broken files it crashes the whole process (segfault).
        return ezc3d.c3d(str(path), extract_forceplat_data=False)
    except (RuntimeError, OSError, ValueError, IndexError) as exc:
        msg = str(exc).replace("\n", " ").strip() or type(exc).__name__
        raise MocapFileError(f"{path}: ezc3d cannot read this C3D file: {msg}") from exc


def read_c3d(path: str | os.PathLike, markers_only: bool = True) -> Markers:
    """Read marker trajectories from a C3D file.

    Parameters
    ----------
    path : the ``.c3d`` file.
    markers_only : drop model outputs listed under ``POINT:ANGLES/FORCES/MOMENTS/POWERS/SCALARS/
        MODELED_MARKERS``, Plug-in-Gait virtual axis points (``PELO``, ``LFEA``, …, ``Centre*``) and the
        unlabelled ``*N`` points, keeping physical markers only.

    Returns
    -------
    Markers with ``points [T, M, 3]`` in cm (NaN where missing), ``visible [T, M]``, labels and rate in Hz.

    Raises
    ------
    MocapFileError naming the file when ezc3d rejects it or it holds no usable marker data.
    """
    path = Path(path)
    c3d = _load(path)
    point = c3d["parameters"].get("POINT", {})
    labels = [str(s).strip() for s in (_param(point, "LABELS", []) or [])]
    data = np.asarray(c3d["data"]["points"], dtype=np.float64)  # [4, M, T]
    if data.shape[1] == 0 or data.shape[2] == 0:
        raise MocapFileError(f"{path}: no POINT data (0 markers or 0 frames)")
    n_points = data.shape[1]
    if len(labels) < n_points:
        labels += [f"point{i}" for i in range(len(labels), n_points)]
    labels = labels[:n_points]
    rate = float((_param(point, "RATE", None) or [0.0])[0])
    if not rate > 0:
        rate = float(c3d["header"]["points"]["frame_rate"])
    if not rate > 0:
        raise MocapFileError(f"{path}: point rate is {rate}, expected a positive number of Hz")
    units = str((_param(point, "UNITS", None) or ["mm"])[0]).strip().lower()
    if units not in _UNIT_TO_CM:
        raise MocapFileError(f"{path}: unknown POINT:UNITS {units!r} (expected one of {sorted(_UNIT_TO_CM)})")

    xyz = data[:3].transpose(2, 1, 0) * _UNIT_TO_CM[units]  # [T, M, 3]
    residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)[0].T  # [T, M]
    visible = np.isfinite(xyz).all(axis=2) & ~(xyz == 0).all(axis=2) & (residuals >= 0)

    keep = np.arange(n_points)
    if markers_only:
        model = {str(s).strip() for g in _MODEL_OUTPUT_GROUPS for s in (_param(point, g, []) or [])}
        keep = np.array(
            [
                i
                for i, lab in enumerate(labels)
                if lab not in model
                and not lab.rsplit(":", 1)[-1].startswith("*")
                and not _PIG_VIRTUAL.match(lab.rsplit(":", 1)[-1])
            ],
            dtype=int,
        )
        if keep.size == 0:
            raise MocapFileError(f"{path}: all {n_points} points are model outputs or unlabelled; no markers")
    xyz, visible = xyz[:, keep], visible[:, keep]
    if not visible.any():
        raise MocapFileError(
            f"{path}: every marker sample is missing (NaN, exactly zero or negative residual): no usable data"
        )
    return Markers(xyz, visible, [labels[i] for i in keep], rate, name=path.name)


def write_c3d(path: str | os.PathLike, markers: Markers, inputs: tuple = ()) -> None:
    """Write markers to a new C3D file (positions in mm, missing samples as NaN with residual -1).

    The file is written to a temporary name and moved into place only when complete; ``inputs`` lists
    source paths the output must not overwrite.
    """
    import ezc3d

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(markers.fps)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(markers.labels)
    c3d.add_parameter("POINT", "UNITS", ["mm"])
    pts = np.ones((4, markers.n_markers, markers.n_frames))
    pts[:3] = (markers.points * 10.0).transpose(2, 1, 0)
    pts[:3][:, ~markers.visible.T] = np.nan
    c3d["data"]["points"] = pts
    with atomic_output(path, inputs) as tmp:
        c3d.write(str(tmp))
