"""Data-driven filling of long gaps in point trajectories: k nearest poses from a database of clean motion,
then an energy minimisation that makes the missing points' positions, velocities and accelerations agree
with those examples (after the kNN completion paper, "Data-driven completion of motion capture data").

Works on any point trajectories: C3D markers, or BVH joint positions as ``Markers`` (one point per joint).

Pipeline (``fill_gaps``):

1. **Normalisation.** Every pose (database and query) is expressed in a body frame: origin = mean of the
   anchor points, heading = the left→right anchor vector projected on the ground plane, up = the world's
   up axis (auto: the axis along which the body's median extent is largest; its positive direction is up).
   Anchors are detected from the labels (``Subject:`` prefixes ignored): Plug-in-Gait LASI/LPSI ↔
   RASI/RPSI, CMU LFWT/LBWT ↔ RFWT/RBWT, or skeleton joints (left/right up-leg or thigh joints plus
   ``Hips``/``Pelvis``). With an unknown marker set the origin is the centroid of all points and the heading
   the first principal horizontal direction of the points, its sign kept continuous over time; that sign is
   arbitrary per clip (a clip's frame may be turned by 180° relative to another's), which weakens the search.
   Frames whose anchors are not all visible (a skeleton's up-leg joints belong to its leg segments) take
   the frame of backup anchors — the shoulders (LSHO/RSHO, or shoulder/clavicle joints) — composed with the
   pelvis-in-shoulder offset interpolated from the frames that have both, i.e. the pelvis is carried
   rigidly with the shoulders through the gap; without backup anchors the origin and heading are
   interpolated (linearly, angle unwrapped) from the nearest frames that have them.
2. **Database** (``MotionDatabase``): normalised positions with velocities (cm/s) and accelerations (cm/s²)
   by central differences, at ``levels`` resolutions r_i = r_max / 2^i (every 2^i-th frame), so the store
   is below twice the full-rate one. Markers are matched by label; clips may miss markers (NaN, excluded
   from the search where needed).
3. **Gaps.** A *gap* is a maximal run of frames in which at least one point is missing. Its search features
   are the points that are reliable (static flags, option ``reliable``) and visible in every frame of the
   gap; its unknowns are the missing samples of the points missing somewhere in it.
4. **Search.** Per gap and per resolution a ``scipy.spatial.cKDTree`` is built over the database frames
   (features = normalised coordinates of the feature points; rows where a feature or unknown point is
   invalid are left out, as is the clip being cleaned) and queried with each gap frame's k nearest poses.
   Neighbour i of frame t gets the kernel weight ``1 / (d_i² + ε²)``, normalised to sum 1 (ε = 10⁻³ cm): an
   exact match dominates, distant poses count less.
5. **Synthesis.** Unknowns x (normalised coordinates) minimise, over missing samples only,
   ``E = Σ_t Σ_i w_ti (|y_ti - x_t|² + |ν_ti Δt - ν(x)_t Δt|² + |α_ti Δt² - α(x)_t Δt²|²)`` (E_pose +
   E_motion + E_smooth), with ``ν(x)_t Δt = (x_{t+1} - x_{t-1}) / 2`` and
   ``α(x)_t Δt² = x_{t+1} - 2 x_t + x_{t-1}`` on the current resolution's grid (Δt = 2^i / fps). Since the
   weights sum to one, each term equals the distance to the weighted mean of the neighbours plus a constant
   (their spread), which is left out of the reported energy. Visible samples are constants: they are never
   changed, and they tie the gap's ends through the derivative terms. Minimisation is L-BFGS
   (``scipy.optimize``) with the analytic gradient, coarse to fine: the coarsest resolution starts from the
   neighbours' weighted mean pose; each finer one starts from the coarser result upsampled linearly in
   time; a resolution is left when an iteration lowers the energy by less than ``threshold`` (1 %).
   **Scheduling**: an iteration does not optimise all unknowns; it ranks the gap's frames by their cost
   (their share of E) and optimises only the ``schedule`` fraction with the highest cost together with the
   two frames on each side (the frames coupled to them through the velocity and acceleration terms); the
   other unknowns stay fixed during that iteration. The next iteration re-ranks.
   **Offset** (our extension, option ``offset``, on by default): the neighbours' mean trajectory of each
   missing point is shifted by the difference between its true and prior positions at the visible frames
   just before and after the gap, blended linearly across the gap (the velocity target gets the blend's
   slope), which removes the offset between the database's actors and the clip's.
6. Results are mapped back to the world frame with each frame's transform.

``fill_gaps`` leaves samples of gaps longer than ``max_gap_s`` (per point) as NaN and lists them in its
report. The registered ``knn`` method (``clean(noisy) -> [T, M, 3]``, the harness interface) instead fills
those samples, and any it could not fill, by linear interpolation and warns naming file, marker and frames.
It then blends the fill with interpolation (``blend_points``): by the distance to the nearest observed
frame and the neighbours' spread, so interpolation is kept next to the observed frames and where the
neighbours disagree. Without a database or training clips the take's own frames are the database.

The Gløersen & Federolf PCA gap filler (no database) lives in ``mocapnet.methods.pca`` and is registered
from here as ``pca``.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from mocapnet.corrupt import motion_markers
from mocapnet.fill import runs
from mocapnet.methods.baselines import lerp_fill, spline_fill
from mocapnet.methods.knn_window import (
    _KERNEL_EPS2,
    FillStats,
    Searcher,
    WindowSettings,
    blend_weight,
    edge_seconds,
    estimate_run,
    gather,
    search_gap,
)
from mocapnet.methods.pca import fill_remaining_linear  # importing pca also registers the "pca" method
from mocapnet.methods.registry import MethodContext, register
from mocapnet.methods.rigid import kabsch
from mocapnet.motion import Markers, Motion

# Reliable markers of the paper's Table 1 (CMU/HDM05 41-marker set): the ``reliable=paper`` preset.
PAPER_RELIABLE = (
    "LFHD RFHD LBHD RBHD C7 STRN LELB LWRA LWRB LFIN RELB RWRA RWRB RFIN LKNE LANK LHEE RKNE RANK RHEE"
).split()
# Left / right pelvis markers of known marker sets (first set whose markers are all present wins).
_PELVIS_SETS = ((("LASI", "LPSI"), ("RASI", "RPSI")), (("LFWT", "LBWT"), ("RFWT", "RBWT")))
_LEG_KEYS = ("upleg", "upperleg", "thigh", "femur")
_ROOT_KEYS = ("hips", "pelvis")
_SHOULDER_KEYS = ("shoulder", "clavicle", "collar")
_MIN_RATE_HZ = 15.0  # automatic levels: halve the rate while the coarsest stays at or above this
_SCHEDULE_REACH = 2  # frames on each side of a scheduled frame that are optimised with it
_MAX_ITERATIONS = 200  # per resolution, a safety cap on scheduling iterations


def bare_label(label: str) -> str:
    """Marker label without its ``Subject:`` prefix, upper case (the key markers are matched by)."""
    return label.rsplit(":", 1)[-1].strip().upper()


def _side(label: str) -> str:
    """``"L"``, ``"R"`` or ``""``: the body side a skeleton joint name refers to."""
    n = label.lower()
    if "left" in n or re.search(r"(^l_|_l$|^l(?=[a-z]))", n):
        return "L"
    if "right" in n or re.search(r"(^r_|_r$|^r(?=[a-z]))", n):
        return "R"
    return ""


@dataclass(frozen=True)
class Anchors:
    """Points that define each pose's body frame (bare labels).

    ``origin`` (mean position) with ``left``/``right`` (heading from left to right); ``left`` empty: unknown
    marker set, centroid of ``origin`` and principal horizontal direction. ``backup_left``/``backup_right``
    (shoulders) stand in for frames where a primary anchor is missing: the pelvis is carried rigidly with
    them (see ``body_frames``)."""

    origin: tuple[str, ...]
    left: tuple[str, ...] = ()
    right: tuple[str, ...] = ()
    backup_left: tuple[str, ...] = ()
    backup_right: tuple[str, ...] = ()

    @property
    def kind(self) -> str:
        return "hips" if self.left else "centroid"

    def backup(self) -> Anchors | None:
        """The shoulder anchors as an ``Anchors`` of their own (None when there are none)."""
        if not self.backup_left:
            return None
        return Anchors(self.backup_left + self.backup_right, self.backup_left, self.backup_right)


def _sided(bare: list[str], keys: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """First skeleton joint name on the left and on the right containing one of ``keys`` (or empty)."""
    found = [b for b in bare if any(k in b.lower() for k in keys)]
    left = [b for b in found if _side(b) == "L"][:1]
    right = [b for b in found if _side(b) == "R"][:1]
    return (tuple(left), tuple(right)) if left and right else ((), ())


def detect_anchors(labels: Sequence[str]) -> Anchors:
    """Anchor points for a marker set: PiG / CMU pelvis markers (backup: LSHO/RSHO), else skeleton hips and
    up-leg joints (backup: shoulder/clavicle joints), else every point (centroid fallback, module docs)."""
    bare = [bare_label(lab) for lab in labels]
    shoulders = (("LSHO",), ("RSHO",)) if {"LSHO", "RSHO"} <= set(bare) else ((), ())
    for left, right in _PELVIS_SETS:
        if all(m in bare for m in left + right):
            return Anchors(left + right, left, right, *shoulders)
    left, right = _sided(bare, _LEG_KEYS)
    if left:
        roots = [b for b in bare if b.lower() in _ROOT_KEYS]
        return Anchors(tuple(roots[:1]) + left + right, left, right, *_sided(bare, _SHOULDER_KEYS))
    return Anchors(tuple(bare))


def up_axis(points: np.ndarray) -> int:
    """World up axis (0, 1, 2) of ``points [T, M, 3]``: the one with the largest median per-frame extent."""
    extent = np.nanmax(points, axis=1) - np.nanmin(points, axis=1)
    return int(np.nanargmax(np.nanmedian(extent, axis=0)))


def _interp_frames(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Replace rows of ``values [T, D]`` where ``ok`` is False by linear interpolation over the ok rows."""
    if ok.all():
        return values
    t = np.arange(len(values))
    return np.stack([np.interp(t, t[ok], values[ok, d]) for d in range(values.shape[1])], axis=1)


def _heading_rotations(angle: np.ndarray, up: int) -> np.ndarray:
    """Rotations ``[T, 3, 3]`` with columns right (heading ``angle`` rad in the ground plane), forward, up."""
    a_ax, b_ax = (up + 1) % 3, (up + 2) % 3
    rot = np.zeros((len(angle), 3, 3))
    rot[:, a_ax, 0] = np.cos(angle)
    rot[:, b_ax, 0] = np.sin(angle)
    rot[:, up, 2] = 1.0
    rot[:, :, 1] = np.cross(rot[:, :, 2], rot[:, :, 0])
    return rot


def _raw_frames(
    points: np.ndarray, visible: np.ndarray, bare: list[str], anchors: Anchors, up: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origin ``[T, 3]`` cm, heading ``[T]`` rad and ``ok [T]`` (anchors usable) of every frame."""
    idx = [bare.index(a) for a in anchors.origin]
    a_ax, b_ax = (up + 1) % 3, (up + 2) % 3
    ok = visible[:, idx].all(axis=1)
    origin = np.where(ok[:, None], points[:, idx].mean(axis=1), 0.0)
    if anchors.kind == "hips":
        left = points[:, [bare.index(a) for a in anchors.left]].mean(axis=1)
        right = points[:, [bare.index(a) for a in anchors.right]].mean(axis=1)
        horizontal = np.where(ok[:, None], (right - left)[:, [a_ax, b_ax]], 0.0)
        ok &= np.linalg.norm(horizontal, axis=1) > 1e-6
    else:
        rel = np.where(ok[:, None, None], (points[:, idx] - origin[:, None])[:, :, [a_ax, b_ax]], 0.0)
        vals, vecs = np.linalg.eigh(np.einsum("tmi,tmj->tij", rel, rel))
        horizontal = vecs[:, :, 1]
        ok &= vals[:, 1] - vals[:, 0] > 1e-9
        sign = np.ones(len(horizontal))
        prev = np.array([1.0, 0.0])
        for t in np.flatnonzero(ok):
            if horizontal[t] @ prev < 0:
                sign[t] = -1.0
            prev = horizontal[t] * sign[t]
        horizontal = horizontal * sign[:, None]
    return origin, np.arctan2(horizontal[:, 1], horizontal[:, 0]), ok


def body_frames(
    points: np.ndarray, visible: np.ndarray, labels: Sequence[str], anchors: Anchors, up: int, name: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame body frames of ``points [T, M, 3]`` (cm): origins ``[T, 3]`` (cm) and rotations
    ``[T, 3, 3]`` whose columns are the body's right, forward and up axes in world coordinates.

    A frame where a primary anchor is missing (or the hips are vertical) but the backup anchors are visible
    takes the backup frame composed with the primary-in-backup offset (origin and heading) interpolated
    from the frames that have both: the pelvis moves rigidly with the shoulders. Remaining frames are
    interpolated (origin linearly, heading angle unwrapped) from the frames that have a frame.
    Raises ValueError naming ``name`` when no frame has all anchors or the anchors are absent.
    """
    bare = [bare_label(lab) for lab in labels]
    missing = [a for a in anchors.origin + anchors.left + anchors.right if a not in bare]
    if missing:
        raise ValueError(f"{name or 'clip'}: anchor marker(s) {missing} not among its labels {bare[:10]}…")
    origin, angle, ok = _raw_frames(points, visible, bare, anchors, up)
    if not ok.any():
        raise ValueError(f"{name or 'clip'}: no frame has all anchor points {list(anchors.origin)} visible")
    backup = anchors.backup()
    t = np.arange(len(points))
    if not ok.all() and backup is not None and all(a in bare for a in backup.origin):
        origin2, angle2, ok2 = _raw_frames(points, visible, bare, backup, up)
        both, stand_in = ok & ok2, ~ok & ok2
        if both.any() and stand_in.any():
            rot2 = _heading_rotations(angle2, up)
            offset = _interp_frames(np.einsum("tji,tj->ti", rot2, origin - origin2), both)
            turn = np.interp(t, t[both], np.unwrap(np.angle(np.exp(1j * (angle - angle2)[both]))))
            angle[stand_in] = angle2[stand_in] + turn[stand_in]
            origin[stand_in] = origin2[stand_in] + np.einsum("tij,tj->ti", rot2[stand_in], offset[stand_in])
            ok |= stand_in
    angle = np.interp(t, t[ok], np.unwrap(angle[ok]))
    return _interp_frames(origin, ok), _heading_rotations(angle, up)


def normalise(points: np.ndarray, origin: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """World points ``[T, M, 3]`` (cm) → body-frame coordinates ``[T, M, 3]`` (cm)."""
    return np.einsum("tji,tmj->tmi", rot, points - origin[:, None])


def denormalise(local: np.ndarray, origin: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Body-frame coordinates ``[T, M, 3]`` (cm) → world points ``[T, M, 3]`` (cm)."""
    return np.einsum("tij,tmj->tmi", rot, local) + origin[:, None]


def downsample(x: np.ndarray, level: int) -> np.ndarray:
    """Resolution ``level`` of a trajectory ``[T, ...]``: every ``2**level``-th frame (rate / 2^level)."""
    return x[:: 2**level]


def upsample(coarse: np.ndarray, n_frames: int, level: int) -> np.ndarray:
    """Back to full rate: linear interpolation in time of ``coarse [T_c, ...]`` (frames ``0, 2^level, …``)
    onto ``n_frames`` frames; beyond the last coarse frame the last value is held."""
    t_c = np.arange(len(coarse)) * 2**level
    flat = coarse.reshape(len(coarse), -1)
    t = np.arange(n_frames)
    out = np.stack([np.interp(t, t_c, flat[:, d]) for d in range(flat.shape[1])], axis=1)
    return out.reshape((n_frames,) + coarse.shape[1:])


def derivatives(x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference velocity (units/s) and acceleration (units/s²) of ``x [T, ...]`` sampled every
    ``dt`` seconds; the first and last frames are NaN."""
    vel = np.full_like(x, np.nan)
    acc = np.full_like(x, np.nan)
    vel[1:-1] = (x[2:] - x[:-2]) / (2.0 * dt)
    acc[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / dt**2
    return vel, acc


def auto_levels(fps: float) -> int:
    """Number of resolutions so the coarsest rate stays at or above 15 Hz (at least 1)."""
    return max(1, int(np.floor(np.log2(max(fps, _MIN_RATE_HZ) / _MIN_RATE_HZ))) + 1)


@dataclass
class Level:
    """One resolution of the database: rows are frames of every clip, concatenated.

    positions ``[N, M, 3]`` cm (body frame), velocities ``[N, M, 3]`` cm/s, accelerations ``[N, M, 3]``
    cm/s², valid ``[N, M]`` (all three defined), clip ``[N]`` index into ``MotionDatabase.clip_names``.
    """

    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    valid: np.ndarray
    clip: np.ndarray

    @property
    def nbytes(self) -> int:
        arrays = (self.positions, self.velocities, self.accelerations, self.valid, self.clip)
        return int(sum(a.nbytes for a in arrays))


def _as_markers(clip: Markers | Motion) -> Markers:
    """A database clip as points: ``Markers`` as they are, a ``Motion`` as its joint positions."""
    return clip if isinstance(clip, Markers) else motion_markers(clip)


@dataclass
class MotionDatabase:
    """Clean motions of one marker set, normalised and stored at several resolutions (see module docs).

    ``labels`` are bare labels (union over clips), ``levels[i]`` holds resolution rate / 2^i. ``source``
    describes where the clips came from (for error messages).
    """

    labels: tuple[str, ...]
    clip_names: tuple[str, ...]
    levels: list[Level]
    anchors: Anchors
    up: str = "auto"
    source: str = ""

    @classmethod
    def from_markers(
        cls,
        clips: Sequence[Markers | Motion],
        levels: int | None = None,
        anchors: Anchors | None = None,
        up: str = "auto",
        source: str = "",
    ) -> MotionDatabase:
        """Build from clean clips (``Markers``, or ``Motion`` whose joint positions are used).

        ``levels``: number of resolutions (default: ``auto_levels`` of the highest clip rate).
        ``up``: ``"auto"`` or ``"x"``/``"y"``/``"z"``.
        """
        markers = [_as_markers(c) for c in clips]
        if not markers:
            raise ValueError("knn: the database is empty (no clean clip given)")
        labels: list[str] = []
        for m in markers:
            labels += [b for b in map(bare_label, m.labels) if b not in labels]
        anchors = anchors or detect_anchors(labels)
        n_levels = levels or auto_levels(max(m.fps for m in markers))
        column = {lab: i for i, lab in enumerate(labels)}
        per_level: list[list[tuple[np.ndarray, ...]]] = [[] for _ in range(n_levels)]
        for ci, m in enumerate(markers):
            bare = [bare_label(lab) for lab in m.labels]
            if len(set(bare)) < len(bare):
                dups = sorted({b for b in bare if bare.count(b) > 1})
                raise ValueError(f"{m.name or 'clip'}: duplicate marker labels {dups} (Subject: prefixes removed)")
            origin, rot = body_frames(m.points, m.visible, m.labels, anchors, _up_index(up, m.points), m.name)
            local = np.full((m.n_frames, len(labels), 3), np.nan)
            cols = [column[b] for b in bare]
            local[:, cols] = normalise(m.points, origin, rot)
            for lev in range(n_levels):
                pos = downsample(local, lev)
                vel, acc = derivatives(pos, 2**lev / m.fps)
                valid = np.isfinite(pos).all(-1) & np.isfinite(vel).all(-1) & np.isfinite(acc).all(-1)
                per_level[lev].append((pos, vel, acc, valid, np.full(len(pos), ci)))
        stacked = [Level(*(np.concatenate(parts) for parts in zip(*rows))) for rows in per_level]
        return cls(tuple(labels), tuple(m.name for m in markers), stacked, anchors, up, source)

    @classmethod
    def from_folders(
        cls, folders: str | os.PathLike | Sequence[str | os.PathLike], levels: int | None = None, up: str = "auto"
    ) -> MotionDatabase:
        """Build from every ``.c3d`` file in one folder or several (``read_folders``)."""
        clips, source = read_folders(folders)
        return cls.from_markers(clips, levels, up=up, source=source)

    @property
    def nbytes(self) -> int:
        """Bytes held by all resolutions."""
        return sum(level.nbytes for level in self.levels)

    def describe(self) -> str:
        """One line naming the database for error messages."""
        where = self.source or f"{len(self.clip_names)} clip(s) {list(self.clip_names[:3])}"
        return f"database {where} ({len(self.labels)} markers)"

    def checked_columns(self, markers: Markers) -> np.ndarray:
        """``columns``, raising ValueError naming the file and the database when the database lacks a point
        that has missing samples."""
        cols = self.columns(markers)
        lacking = [markers.labels[i] for i in np.flatnonzero((cols < 0) & ~markers.visible.all(axis=0))]
        if lacking:
            raise ValueError(
                f"{markers.name or 'markers'}: {self.describe()} does not contain marker(s) {lacking} of this file; "
                f"the database's markers are {list(self.labels)}, the file's {[bare_label(x) for x in markers.labels]}"
            )
        return cols

    def columns(self, markers: Markers) -> np.ndarray:
        """Database column of each of ``markers``' points (``[M]`` int, -1 where the database lacks it)."""
        column = {lab: i for i, lab in enumerate(self.labels)}
        return np.array([column.get(bare_label(lab), -1) for lab in markers.labels], dtype=int)


def read_folders(folders: str | os.PathLike | Sequence[str | os.PathLike]) -> tuple[list[Markers], str]:
    """Every ``.c3d`` file in one folder or several (a sequence, or one string joined with ``os.pathsep``),
    and the folders as one string. Files ezc3d cannot read are skipped with a warning."""
    from mocapnet.io import MocapFileError, read_c3d

    if isinstance(folders, (str, os.PathLike)):
        folders = [f for f in str(folders).split(os.pathsep) if f]
    clips = []
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise ValueError(f"knn: database folder {folder} does not exist")
        for path in sorted(p for p in folder.iterdir() if p.suffix.lower() == ".c3d"):
            try:
                clips.append(read_c3d(path))
            except MocapFileError as exc:
                warnings.warn(f"knn: database file skipped: {exc}", stacklevel=2)
    if not clips:
        raise ValueError(f"knn: no readable .c3d file in database folder(s) {[str(f) for f in folders]}")
    return clips, ", ".join(map(str, folders))


def _up_index(up: str, points: np.ndarray) -> int:
    if up == "auto":
        return up_axis(points)
    if up not in ("x", "y", "z"):
        raise ValueError(f"knn: up must be auto, x, y or z, got {up!r}")
    return "xyz".index(up)


@dataclass
class FillReport:
    """What ``fill_gaps`` did: gaps filled, samples left unfilled (``(label, first, last, reason)``, frames
    0-based inclusive), CPU seconds (``time.process_time``) spent building kd-trees, querying them and
    optimising, kd-tree queries made and scheduling iterations run; ``spread [T, M]`` (cm): the kernel-weighted
    RMS distance of the neighbours' positions of each missing sample to their mean at the finest resolution
    (NaN elsewhere), how much the neighbours disagree."""

    gaps: int = 0
    unfilled: list[tuple[str, int, int, str]] = field(default_factory=list)
    build_s: float = 0.0
    query_s: float = 0.0
    solve_s: float = 0.0
    queries: int = 0
    iterations: int = 0
    spread: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


class _Energy:
    """E_pose + E_motion + E_smooth on one resolution's grid, for the unknowns of one gap.

    ``X [n, P, 3]`` holds every sample (NaN where unknown and not a variable: no term uses it);
    ``var [n, P]`` marks the variables; ``pos``, ``vel``, ``acc`` ``[n, P, 3]`` hold the neighbours' weighted
    mean position, velocity·Δt and acceleration·Δt² (cm). ``value_grad`` and ``frame_cost`` take ``X`` with
    the undefined samples set to any finite value.
    """

    def __init__(self, X: np.ndarray, var: np.ndarray, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray):
        self.defined = var | np.isfinite(X).all(axis=-1)
        self.var = var
        self.motion = np.zeros_like(var)
        self.motion[1:-1] = var[1:-1] & self.defined[:-2] & self.defined[2:]
        self.targets = (pos, vel, acc)

    def residuals(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos, vel, acc = self.targets
        r_pose = (pos - X) * self.var[..., None]
        r_vel = np.zeros_like(X)
        r_acc = np.zeros_like(X)
        r_vel[1:-1] = vel[1:-1] - (X[2:] - X[:-2]) / 2.0
        r_acc[1:-1] = acc[1:-1] - (X[2:] - 2.0 * X[1:-1] + X[:-2])
        m = self.motion[..., None]
        return r_pose, r_vel * m, r_acc * m

    def value_grad(self, X: np.ndarray) -> tuple[float, np.ndarray]:
        r_pose, r_vel, r_acc = self.residuals(X)
        energy = float((r_pose**2).sum() + (r_vel**2).sum() + (r_acc**2).sum())
        grad = -2.0 * r_pose
        # Adjoints of the stencils (X[t+1] - X[t-1]) / 2 and X[t+1] - 2 X[t] + X[t-1].
        grad[1:] -= r_vel[:-1]
        grad[:-1] += r_vel[1:]
        grad[1:] -= 2.0 * r_acc[:-1]
        grad[:-1] -= 2.0 * r_acc[1:]
        grad += 4.0 * r_acc
        return energy, grad

    def frame_cost(self, X: np.ndarray) -> np.ndarray:
        """Each frame's share of the energy, ``[n]``."""
        return sum((r**2).sum(axis=(1, 2)) for r in self.residuals(X))


def _on_subset(energy: _Energy, X: np.ndarray, idx: tuple[np.ndarray, np.ndarray]):
    """Energy and gradient as a function of the flattened samples ``X[idx]`` only (the others fixed)."""

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        trial = X.copy()
        trial[idx] = x.reshape(-1, 3)
        value, grad = energy.value_grad(trial)
        return value, grad[idx].ravel()

    return fun


def _minimise(energy: _Energy, X: np.ndarray, schedule: float, threshold: float, inner: int) -> tuple[np.ndarray, int]:
    """Scheduled L-BFGS on the variables of ``X`` until an iteration gains less than ``threshold``."""
    var_frames = np.flatnonzero(energy.var.any(axis=1))
    n_sched = max(1, int(np.ceil(schedule * len(var_frames))))
    value, _ = energy.value_grad(X)
    iterations = 0
    while iterations < _MAX_ITERATIONS and value > 1e-12:
        iterations += 1
        cost = energy.frame_cost(X)[var_frames]
        top = var_frames[np.argsort(cost)[-n_sched:]]
        chosen = np.zeros(len(X), dtype=bool)
        for offset in range(-_SCHEDULE_REACH, _SCHEDULE_REACH + 1):
            chosen[np.clip(top + offset, 0, len(X) - 1)] = True
        idx = np.nonzero(energy.var & chosen[:, None])
        res = minimize(
            _on_subset(energy, X, idx), X[idx].ravel(), jac=True, method="L-BFGS-B", options={"maxiter": inner}
        )
        X[idx] = res.x.reshape(-1, 3)
        gain = value - float(res.fun)
        value = float(res.fun)
        if gain <= threshold * (value + gain):
            break
    return X, iterations


def _reliable_mask(markers: Markers, reliable: str | Sequence[str] | None) -> np.ndarray:
    """Static per-point flags ``[M]``: all (None/``"all"``), the paper's Table 1 (``"paper"``), or labels
    (a sequence, or one string joined with ``+``)."""
    if reliable is None or reliable == "all":
        return np.ones(markers.n_markers, dtype=bool)
    names = PAPER_RELIABLE if reliable == "paper" else reliable
    if isinstance(names, str):
        names = names.split("+")
    wanted = {bare_label(n) for n in names}
    mask = np.array([bare_label(lab) in wanted for lab in markers.labels])
    if not mask.any():
        raise ValueError(f"{markers.name or 'markers'}: no marker matches the reliable set {sorted(wanted)[:8]}")
    return mask


@dataclass(frozen=True)
class _Settings:
    k: int
    n_levels: int
    schedule: float
    threshold: float
    inner: int
    offset: bool
    cluster: int = 0


def fill_gaps(
    markers: Markers,
    database: MotionDatabase,
    k: int = 32,
    reliable: str | Sequence[str] | None = None,
    levels: int | None = None,
    max_gap_s: float | None = None,
    schedule: float = 0.25,
    threshold: float = 0.01,
    inner: int = 30,
    offset: bool = True,
    exclude: str | None = None,
    cluster: int = 0,
) -> tuple[np.ndarray, FillReport]:
    """Fill the missing samples of ``markers`` from similar poses of ``database`` (see module docstring).

    Parameters
    ----------
    markers : points ``[T, M, 3]`` (cm), missing where ``visible`` is False.
    database : clean motion of the same marker set.
    k : neighbours per frame.
    reliable : static search flags: None/"all", "paper" (Table 1 of the paper), or labels ("A+B" or list).
    levels : resolutions (default: ``auto_levels(markers.fps)``, capped by the database's).
    max_gap_s : a point missing for longer than this many seconds in a row is left NaN (and reported).
    schedule : fraction of a gap's frames (highest cost first) optimised per iteration.
    threshold : relative energy gain below which a resolution is left for the next finer one.
    inner : L-BFGS iterations per scheduling iteration.
    offset : our extension, on by default (not in the paper): shift the neighbours' mean trajectory of
        each missing point by the difference between the point's true and prior positions at the visible
        frames just before and after the gap, blended linearly across it (one side only: constant). It
        removes the offset between the database's actors and the clip's and makes the fill continuous.
    exclude : clip name left out of the database (the clip being cleaned), default ``markers.name``; ``""``
        leaves nothing out (the take is its own database).
    cluster : with ``n >= 3``, the missing points of every neighbour are expressed relative to the nearest
        visible rigid cluster: the ``n`` feature points nearest the gap's unknown points (in the neighbours'
        poses). Each neighbour pose's cluster is fitted to the query frame's (``rigid.kabsch``: rotation and
        translation, least squares) and its unknown points (velocities, accelerations: rotation only) move
        with it, so a neighbour with the trunk bent otherwise still places the arm right on the trunk.
        0 (default): body frame only.

    Returns
    -------
    points ``[T, M, 3]`` cm: visible samples unchanged, missing ones filled, NaN where not filled; and a
    ``FillReport``.

    Raises
    ------
    ValueError naming the file and the database when the database lacks a point that has missing samples.
    """
    report = FillReport(spread=np.full(markers.visible.shape, np.nan))
    name = markers.name or "markers"
    cols = database.checked_columns(markers)
    todo = ~markers.visible & (cols >= 0)[None]
    if max_gap_s is not None:
        limit = int(round(max_gap_s * markers.fps))
        for m in np.flatnonzero(todo.any(axis=0)):
            for a, b in runs(todo[:, m]):
                if b - a > limit:
                    todo[a:b, m] = False
                    report.unfilled.append((markers.labels[m], int(a), int(b - 1), f"longer than {max_gap_s:g} s"))
    up = _up_index(database.up, markers.points)
    origin, rot = body_frames(markers.points, markers.visible, markers.labels, database.anchors, up, name)
    local = normalise(markers.points, origin, rot)
    usable = _reliable_mask(markers, reliable) & (cols >= 0)
    settings = _Settings(
        k, min(levels or auto_levels(markers.fps), len(database.levels)), schedule, threshold, inner, offset, cluster
    )
    excluded = markers.name if exclude is None else exclude
    keep_clip = np.array([not excluded or c != excluded for c in database.clip_names])
    for a, b in runs(todo.any(axis=1)):
        unknown = np.flatnonzero(todo[a:b].any(axis=0))
        features = np.flatnonzero(usable & markers.visible[a:b].all(axis=0))
        if features.size == 0:
            for m in unknown:
                report.unfilled.append((markers.labels[m], int(a), int(b - 1), "no reliable point visible"))
            continue
        report.gaps += 1
        gap = _Gap(local, todo, (a, b), unknown, features, cols, database, keep_clip, markers.fps)
        gap.solve(settings, report)
    out = markers.points.copy()
    done = todo & np.isfinite(local).all(axis=-1)
    out[done] = denormalise(local, origin, rot)[done]
    return out, report


@dataclass
class _Gap:
    """One gap ``span = [a, b)`` of ``local`` (body-frame points ``[T, M, 3]``, modified in place by
    ``solve``): its unknown and feature points (indices into M) and the database columns of every point."""

    local: np.ndarray
    todo: np.ndarray
    span: tuple[int, int]
    unknown: np.ndarray
    features: np.ndarray
    cols: np.ndarray
    database: MotionDatabase
    keep_clip: np.ndarray
    fps: float

    def solve(self, settings: _Settings, report: FillReport) -> None:
        """Coarse-to-fine synthesis of the unknowns (module docstring, step 5)."""
        a, b = self.span
        pad = 2 * 2 ** (settings.n_levels - 1)
        w0, w1 = max(0, a - pad), min(len(self.local), b + pad)
        solution: tuple[np.ndarray, np.ndarray] | None = None
        for lev in reversed(range(settings.n_levels)):
            frames = np.arange(w0, w1, 2**lev)
            X = self.local[frames][:, self.unknown].copy()
            var = self.todo[frames][:, self.unknown] & ((frames >= a) & (frames < b))[:, None]
            if not var.any():
                continue  # the gap falls between this resolution's frames
            targets = self.targets(lev, frames, var, settings, report)
            X[var] = (targets[0] if solution is None else _resample(*solution, frames))[var]
            t0 = time.process_time()
            energy = _Energy(X, var, *targets)
            X, its = _minimise(
                energy,
                np.where(energy.defined[..., None], X, 0.0),
                settings.schedule,
                settings.threshold,
                settings.inner,
            )
            X[~energy.defined] = np.nan  # samples of other gaps: unknown here, never used as values
            report.solve_s += time.process_time() - t0
            report.iterations += its
            solution = (frames, X)
        frames, X = solution  # the finest grid holds every frame, so it always has variables
        var = self.todo[frames][:, self.unknown] & ((frames >= a) & (frames < b))[:, None]
        block = self.local[frames][:, self.unknown]
        block[var] = X[var]
        self.local[np.ix_(frames, self.unknown)] = block

    def targets(
        self, lev: int, frames: np.ndarray, var: np.ndarray, settings: _Settings, report: FillReport
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Kernel-weighted mean of the k nearest database poses of every grid frame with unknowns:
        positions, velocities·Δt and accelerations·Δt² of the unknown points, each ``[n, P, 3]`` cm (zero
        on frames without unknowns), Δt = ``2**lev / fps``."""
        level = self.database.levels[lev]
        f_cols, u_cols = self.cols[self.features], self.cols[self.unknown]
        rows = np.flatnonzero(
            level.valid[:, f_cols].all(axis=1) & level.valid[:, u_cols].all(axis=1) & self.keep_clip[level.clip]
        )
        if rows.size == 0:
            raise ValueError(f"{self.database.describe()}: no frame where the gap's markers are all valid")
        a, b = self.span
        query = np.flatnonzero(var.any(axis=1))
        ends = np.array([f for f in (a - 1, b) if 0 <= f < len(self.local)], dtype=int)
        t0 = time.process_time()
        tree = cKDTree(level.positions[np.ix_(rows, f_cols)].reshape(rows.size, -1))
        t1 = time.process_time()
        asked = np.concatenate([frames[query], ends]) if settings.offset else frames[query]
        kk = min(settings.k, rows.size)
        dist, idx = tree.query(self.local[asked][:, self.features].reshape(len(asked), -1), k=list(range(1, kk + 1)))
        report.build_s += t1 - t0
        report.query_s += time.process_time() - t1
        report.queries += len(asked)
        weights = 1.0 / (dist**2 + _KERNEL_EPS2)
        weights /= weights.sum(axis=1, keepdims=True)
        hits = rows[idx]
        dt = 2**lev / self.fps
        near = [data[hits[..., None], u_cols] for data in (level.positions, level.velocities, level.accelerations)]
        if settings.cluster >= 3:
            near = self._on_cluster(level.positions, hits, asked, near, settings.cluster)
        means = [np.einsum("qk,qkpc->qpc", weights, x) * scale for x, scale in zip(near, (1.0, dt, dt**2))]
        if lev == 0:
            spread = np.einsum("qk,qkp->qp", weights, ((near[0] - means[0][:, None]) ** 2).sum(-1))
            report.spread[np.ix_(frames[query], self.unknown)] = np.sqrt(spread[: len(query)])
        out = []
        for mean in means:
            full = np.zeros((len(frames), len(self.unknown), 3))
            full[query] = mean[: len(query)]
            out.append(full)
        if settings.offset:
            shift, slope = self._offsets(ends, means[0][len(query) :], frames)
            out[0] += shift * var[..., None]
            out[1] += slope * 2**lev * var[..., None]
        return out[0], out[1], out[2]

    def _on_cluster(
        self, positions: np.ndarray, hits: np.ndarray, asked: np.ndarray, near: list[np.ndarray], n: int
    ) -> list[np.ndarray]:
        """``near`` (positions, velocities, accelerations of the unknown points ``[q, k, U, 3]`` of the
        neighbours ``hits [q, k]`` of frames ``asked [q]``) moved with the rigid fit of each neighbour's
        cluster onto the query frame's: the ``n`` feature points nearest the unknown points."""
        f_cols, u_cols = self.cols[self.features], self.cols[self.unknown]
        nearest = positions[hits[:, 0]]  # [q, M_db, 3]: each frame's nearest neighbour
        centre = nearest[:, u_cols].mean(axis=1, keepdims=True)
        order = np.argsort(np.linalg.norm(nearest[:, f_cols] - centre, axis=-1).mean(axis=0))[:n]
        src = positions[hits[..., None], f_cols[order]]  # [q, k, n, 3]
        dst = np.broadcast_to(self.local[asked][:, self.features[order]][:, None], src.shape)
        rot, shift = kabsch(src, dst)
        return [
            np.einsum("qkij,qkuj->qkui", rot, x) + (shift[:, :, None] if i == 0 else 0.0) for i, x in enumerate(near)
        ]

    def _offsets(self, ends: np.ndarray, prior: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame shift ``[n, P, 3]`` and per-frame slope ``[P, 3]`` (cm) of the ``offset`` extension:
        true minus prior position at the visible frames before / after the gap, blended linearly."""
        a, b = self.span
        missing = np.full((len(self.unknown), 3), np.nan)
        found = {int(f): self.local[f, self.unknown] - prior[i] for i, f in enumerate(ends)}
        before, after = found.get(a - 1, missing), found.get(b, missing)
        before, after = np.where(np.isnan(before), after, before), np.where(np.isnan(after), before, after)
        before, after = np.nan_to_num(before), np.nan_to_num(after)
        slope = (after - before) / (b - a + 1)
        return before + slope * (frames - (a - 1))[:, None, None], slope


def _resample(frames_c: np.ndarray, values: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Linear interpolation in time of ``values [n_c, P, 3]`` (finite samples only) onto ``frames``."""
    out = np.full((len(frames),) + values.shape[1:], np.nan)
    for p in range(values.shape[1]):
        ok = np.isfinite(values[:, p]).all(axis=-1)
        if ok.any():
            for c in range(3):
                out[:, p, c] = np.interp(frames, frames_c[ok], values[ok, p, c])
    return out


def fill_markers(
    markers: Markers,
    database: MotionDatabase,
    settings: WindowSettings | None = None,
    exclude: str | None = None,
) -> tuple[np.ndarray, FillStats]:
    """Fill the missing samples of ``markers`` (points ``[T, M, 3]`` cm) from the nearest windows of the
    database's full-rate poses (normalised as in ``knn``) and, with ``settings.own``, of the take's own fully
    visible frames; each coordinate is filled like a channel in ``knn_angles`` (``speed`` and the spread in
    cm). Points near the gap weigh ``1 + near_gain / max(1, d / 10 cm)`` (d: distance to the nearest missing
    point at the gap's edge). ``exclude``: clip left out of the database (default ``markers.name``).
    Returns points ``[T, M, 3]`` (observed samples unchanged) and stats. Raises ValueError naming the file
    when the database lacks a point with missing samples."""
    t_start = time.process_time()
    settings = settings or WindowSettings()
    if settings.fallback != "lerp":
        raise ValueError(f"knn: point data falls back to lerp only, got fallback={settings.fallback!r}")
    stats = FillStats()
    name = markers.name or "markers"
    cols = database.checked_columns(markers)
    missing = ~markers.visible
    n_t, n_m = missing.shape
    up = _up_index(database.up, markers.points)
    origin, rot = body_frames(markers.points, markers.visible, markers.labels, database.anchors, up, name)
    local = normalise(markers.points, origin, rot)
    base = lerp_fill(local.reshape(n_t, 3 * n_m), np.repeat(missing, 3, axis=1)).reshape(n_t, n_m, 3)
    out = base.copy()
    mapped = np.flatnonzero(cols >= 0)
    level = database.levels[0]
    skip = markers.name if exclude is None else exclude
    allowed = level.valid[:, cols[mapped]].all(axis=1) & np.array([c != skip for c in database.clip_names])[level.clip]
    searcher = Searcher(level.positions[:, cols[mapped]], level.clip, database.describe())
    complete = ~missing.any(axis=1)
    own = Searcher(base[:, mapped], np.zeros(n_t, dtype=int), f"{name} itself") if settings.own else None
    seconds = edge_seconds(missing, markers.fps)
    for a, b in runs(missing.any(axis=1)):
        unknown = np.flatnonzero(missing[a:b].any(axis=0))  # indices into markers (all mapped)
        edge = a - 1 if a > 0 else min(b, n_t - 1)
        near = np.linalg.norm(base[edge, mapped][:, None] - base[edge, unknown][None], axis=-1).min(axis=1)
        gain = 1.0 + settings.near_gain / np.maximum(1.0, near / 10.0)
        nb = search_gap(
            searcher, own, base[:, mapped], markers.visible[:, mapped], gain, (a, b), markers.fps, settings, allowed,
            complete, stats,
        )  # fmt: skip
        lo = nb.span[0]
        traj = gather(level.positions[:, cols[unknown]], base[:, unknown], nb.starts, nb.from_own, nb.span - nb.w0)
        for u, m in enumerate(unknown):
            for c0, c1 in runs(missing[lo : nb.span[-1] + 1, m]):
                run = (c0 + lo, c1 + lo)
                for c in range(3):
                    b_c = base[:, m, c]
                    t, est, beta = estimate_run(
                        b_c, traj[:, :, u, c], nb.kernel, seconds[:, m], lo, run, nb.rms, settings
                    )
                    out[t, m, c] = np.where(beta == 1.0, est, b_c[t] + beta * (est - b_c[t]))  # β = 1: est exactly
    result = markers.points.copy()
    result[missing] = denormalise(out, origin, rot)[missing]
    stats.total_s = time.process_time() - t_start
    return result, stats


def blend_points(
    noisy: Markers, filled: np.ndarray, spread: np.ndarray, speed: float | None, base: str = "lerp"
) -> np.ndarray:
    """``base + β (filled - base)`` on the missing samples of ``noisy`` (``filled [T, M, 3]`` cm, finite),
    β = ``blend_weight(spread [T, M] cm, edge_seconds, speed cm/s)``; ``base`` is ``lerp`` or ``spline``
    interpolation of each coordinate. ``speed`` None returns ``filled``. Observed samples are unchanged."""
    if speed is None:
        return filled
    if base not in ("lerp", "spline"):
        raise ValueError(f"knn: base must be lerp or spline, got {base!r}")
    t, m = noisy.visible.shape
    fill = lerp_fill if base == "lerp" else spline_fill
    interp = fill(noisy.points.reshape(t, m * 3), np.repeat(~noisy.visible, 3, axis=1)).reshape(t, m, 3)
    beta = blend_weight(spread, edge_seconds(~noisy.visible, noisy.fps), speed)
    out = interp + beta[..., None] * (filled - interp)
    out[noisy.visible] = noisy.points[noisy.visible]
    return out


@register(
    "knn",
    "points",
    help="kNN from a clean database (default search=energy: the paper's per-frame kd-tree + energy "
    "minimisation; search=window: nearest windows), offset-corrected, blended with interpolation; options k, "
    "database=<folder>, own, "
    "speed, offset, margin_s, near_gain, query_hz, distance_gain, search; energy: levels, reliable, max_gap_s, "
    "schedule, threshold, base, cluster; up",
)
def _knn(
    context: MethodContext,
    k: int = 16,
    database: str | None = None,
    search: str = "energy",
    own: bool = True,
    offset: bool = True,
    speed: float | None = 150.0,
    up: str = "auto",
    levels: int | None = None,
    reliable: str | None = None,
    max_gap_s: float | None = None,
    schedule: float = 0.25,
    threshold: float = 0.01,
    base: str = "lerp",
    cluster: int = 0,
    **window: float,
) -> Callable[[Markers], np.ndarray]:
    """``knn`` for point data. The database is ``database`` (folder(s) of C3D files, joined with
    ``os.pathsep``) when given, else ``context.train`` (the clip being cleaned, same ``name``, is left out),
    else the take's own frames. ``own``: the take's own fully observed frames join a given database too.
    ``clean.database`` says which. ``search="energy"`` (default): the paper's ``fill_gaps``, blended with
    ``base`` interpolation by ``blend_points``, samples it leaves NaN filled linearly with a warning;
    ``"window"``: ``fill_markers`` (options ``margin_s``, ``near_gain``, ``query_hz``,
    ``distance_gain`` of ``WindowSettings``). ``speed`` in cm/s (None: no blend). Defaults (energy, k 16,
    speed 150 cm/s, own) were chosen on the Plug-in-Gait tennis serve (database: the pyCGM trial), not on
    the 41-marker set the benchmark reports."""
    if search not in ("window", "energy"):
        raise ValueError(f"knn: search must be window or energy, got {search!r}")
    settings = WindowSettings(k=k, speed=speed, offset=offset, own=own, **window)
    levels = 1 if search == "window" else levels  # the window search reads only the finest level
    fixed: MotionDatabase | None = None
    clips: list[Markers] = []
    if database is not None:
        clips, source = read_folders(database)
        fixed = MotionDatabase.from_markers(clips, levels, up=up, source=source)
    elif context.train:
        clips = [c if isinstance(c, Markers) else motion_markers(c) for c in context.train]
        fixed = MotionDatabase.from_markers(clips, levels, up=up, source=context.corpus or "training clips")

    def clean(noisy: Markers) -> np.ndarray:
        take = replace(noisy, name=f"{noisy.name}, own frames")  # not left out as the clip being cleaned
        if fixed is None:
            db = MotionDatabase.from_markers([take], levels, up=up, source=f"{noisy.name or 'the take'}'s own frames")
        elif own and search == "energy":
            db = MotionDatabase.from_markers(clips + [take], levels, up=up, source=f"{fixed.source} + own frames")
        else:
            db = fixed
        clean.database = db.describe() + (" + the take's own frames" if own and fixed and search == "window" else "")  # type: ignore[attr-defined]
        if search == "window":
            return fill_markers(noisy, db, replace(settings, own=own and fixed is not None))[0]
        filled, report = fill_gaps(
            noisy,
            db,
            k=k,
            reliable=reliable,
            levels=levels,
            max_gap_s=max_gap_s,
            schedule=schedule,
            threshold=threshold,
            offset=offset,
            cluster=cluster,
        )
        filled = fill_remaining_linear(
            noisy, filled, "knn left a gap unfilled (too long or no visible reliable marker)"
        )
        return blend_points(noisy, filled, report.spread, speed, base)

    clean.database = fixed.describe() if fixed else "the take's own complete frames"  # type: ignore[attr-defined]
    return clean
