"""Real-time prediction of missing markers from their own past, with an optional constraint-matrix corrector.

A streaming predictor after the extrapolation paper (linear + circular extrapolation blended by a matching
factor, corrected by a matrix of inter-marker distance bounds). No training, no skeleton, no torch: every
frame costs the same few vectorised numpy operations over the markers.

Per missing marker, at each new frame (our reading of the paper, whose equations are lost in the text):

* From the backlog (the last ``backlog`` frames, default 30) take three evenly spaced samples ``s =
  (backlog - 1) // 2`` frames apart: ``P1`` (newest), ``P2``, ``P3`` (oldest). Velocities are chords over the
  spacing, not over consecutive frames: ``v1 = (P1 - P2) / (s dt)``, ``v2 = (P2 - P3) / (s dt)``.
* Linear estimate ``L' = P1 + v1 dt``; the line used for its error passes through the mean of ``P1..P3``
  along ``v1``.
* Circular estimate: the velocity change ``v1 - v2`` points to the centre of rotation. Taken normal to each
  chord velocity at the middle of its chord (where a chord velocity is measured), it gives two lines; their
  closest points ``H``, ``Q`` give ``C = (H + Q) / 2`` (for samples on a circle, its centre exactly). The
  axis is the normal ``v1 x v2`` of the plane of the velocities; the angle between ``P2 - C`` and ``P1 - C``
  over ``s dt`` is ``|ω|``, its sign that of the tangent ``axis x (P1 - C)`` along ``v1``. ``P1`` is
  rotated about the axis through ``C`` by ``ω dt`` with a quaternion: ``C'``.
* Matching factor ``α = e_L / (e_L + e_C)`` from the squared distances of backlog samples (every
  ``max(1, s // 3)``-th frame from ``P1`` to ``P3``) to the line (``e_L``) and to the circle through ``P1``
  (``e_C``: radial and out-of-plane); ``P' = (1 - α) L' + α C'``. Collinear or static samples have no
  circle: ``α = 0`` (linear), never NaN.

Constraint matrix (``constraint_matrix=True``): the smallest and largest distance ever seen between every
pair of simultaneously visible markers, ``[M, M]`` each, updated every frame. Pairs whose ``max - min``
exceeds ``threshold_cm`` (default 10 cm) are not rigid and ignored. Each prediction is moved toward the
distance bounds to every rigid partner: the full correction for a visible partner, half of it when the
partner is itself predicted (the paper's rule). The paper adjusts successively, one partner after the
other; here all partners act at once (the mean of the corrections asked by the violated bounds), repeated
``iterations`` times, which keeps the work vectorised.

Predictions feed the backlog, so long occlusions continue from the predicted path; when the marker
reappears its real data resumes. A marker that has been seen for fewer than ``2 s + 1`` frames holds its
last value. A marker never seen yet has no past at all: the streaming predictor places it at ``initial``
(when given) or else at the centroid of the markers that have a value in that frame (the origin if none);
the whole-array :func:`extrapolate` passes as ``initial`` each marker's first visible value, i.e. the
nearest later visible value fills a gap at the start of a clip.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Markers

MODES = ("hold", "linear", "circular", "blend")
PointsClean = Callable[[Markers], np.ndarray]

# Velocity changes smaller than this fraction of the speed are rounding noise (the samples lie on a line).
_ACCEL_REL_TOL = 1e-8
# Velocity-change directions closer to parallel than this (squared sine of their angle) give no centre.
_PARALLEL_SIN2_TOL = 1e-10
_WARM_UP_CHUNK = 256
_NEXT = np.array([1, 2, 0])
_PREV = np.array([2, 0, 1])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of ``[K, 3]`` arrays (``np.cross`` costs several times more on small arrays)."""
    return a.take(_NEXT, 1) * b.take(_PREV, 1) - a.take(_PREV, 1) * b.take(_NEXT, 1)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of ``[K, 3]`` arrays, ``[K]``."""
    return np.einsum("ij,ij->i", a, b)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(_dot(a, a))


def _normal_part(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a`` minus its component along ``b`` (row-wise, ``[K, 3]``)."""
    bb = _dot(b, b)
    return a - (_dot(a, b) / np.where(bb > 0, bb, 1.0))[:, None] * b


def _unit(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors of ``a [K, 3]`` (zero where ``a`` is zero) and the norms ``[K]``."""
    n = _norm(a)
    return a / np.where(n > 0, n, 1.0)[:, None], n


def predict_next(history: np.ndarray, dt: float, spacing: int, mode: str = "blend") -> np.ndarray:
    """One-frame-ahead prediction of ``K`` points from their own past.

    Parameters
    ----------
    history : ``[A, K, 3]`` positions in cm, newest first (``A >= 2 * spacing + 1``); ``P1 = history[0]``,
        ``P2 = history[spacing]``, ``P3 = history[2 * spacing]``. Every ``max(1, spacing // 3)``-th frame of the
        first ``2 * spacing + 1`` enters the line and circle errors.
    dt : frame period in seconds.
    spacing : frames between the samples ``P1``, ``P2``, ``P3``.
    mode : ``"linear"`` (``L'``), ``"circular"`` (``C'`` where a circle exists, else ``L'``) or ``"blend"``
        (``(1 - α) L' + α C'``).

    Returns
    -------
    ``[K, 3]`` predicted positions in cm, one frame after ``P1``; always finite for finite input.
    """
    p1, p2, p3 = history[0], history[spacing], history[2 * spacing]
    span = spacing * dt
    v1, v2 = (p1 - p2) / span, (p2 - p3) / span
    linear = p1 + v1 * dt
    if mode == "linear":
        return linear
    # Centre of rotation: the closest points H, Q of the lines along which the velocity change v1 - v2 points,
    # taken normal to each chord velocity at the chord's middle (where a chord velocity is measured).
    dv = v1 - v2
    d1, d2 = _normal_part(dv, v1), _normal_part(dv, v2)
    a, b, c = _dot(d1, d1), _dot(d1, d2), _dot(d2, d2)
    w0 = (p1 - p3) / 2  # from the middle of P3P2 to the middle of P2P1
    d, e = _dot(d1, w0), _dot(d2, w0)
    den = a * c - b * b
    accel_tol = (_ACCEL_REL_TOL * (_norm(v1) + _norm(v2))) ** 2
    valid = (a > accel_tol) & (c > accel_tol) & (den > _PARALLEL_SIN2_TOL * a * c)
    den = np.where(valid, den, 1.0)
    h = (p1 + p2) / 2 + ((b * e - c * d) / den)[:, None] * d1
    q = (p2 + p3) / 2 + ((a * e - b * d) / den)[:, None] * d2
    centre = (h + q) / 2
    # Axis: normal of the plane of the two velocities; ω from the angle P2 -> P1 about C, its sign from the
    # tangent direction axis x (P1 - C) along v1.
    axis, axis_len = _unit(_cross(v1, v2))
    c1, c2 = p1 - centre, p2 - centre
    angle = np.arctan2(_norm(_cross(c2, c1)), _dot(c2, c1))
    phi = np.sign(_dot(_cross(axis, c1), v1)) * angle / spacing  # ω dt, radians
    # Quaternion q = (cos φ/2, sin φ/2 · axis); p' = q p q̄ written as v + w t + u x t, t = 2 u x v.
    u = np.sin(phi / 2)[:, None] * axis
    t = 2 * _cross(u, c1)
    circular = centre + c1 + np.cos(phi / 2)[:, None] * t + _cross(u, t)
    valid &= (axis_len > 0) & np.isfinite(circular).all(axis=1)
    if mode == "circular":
        return np.where(valid[:, None], circular, linear)
    # Matching factor from the line and circle errors of the backlog samples.
    samples = history[: 2 * spacing + 1 : max(1, spacing // 3)]
    line_dir, _ = _unit(v1)
    rel = samples - (p1 + p2 + p3) / 3
    off_line = rel - np.einsum("sij,ij->si", rel, line_dir)[..., None] * line_dir
    err_line = np.einsum("sij,sij->i", off_line, off_line)
    rc = samples - centre
    height = np.einsum("sij,ij->si", rc, axis)
    radius = np.linalg.norm(rc - height[..., None] * axis, axis=2)
    err_circle = (((radius - radius[0]) ** 2) + (height - height[0]) ** 2).sum(axis=0)
    total = err_line + err_circle
    alpha = np.where(valid & (total > 0), err_line / np.where(total > 0, total, 1.0), 0.0)
    return np.where(valid[:, None], (1 - alpha)[:, None] * linear + alpha[:, None] * circular, linear)


class Extrapolator:
    """Streaming filler: ``push`` one frame, get it back with every missing marker predicted.

    Parameters
    ----------
    labels : marker labels, length M (kept for messages and callers; the maths does not use them).
    fps : frame rate in Hz.
    mode : ``"hold"`` (last value), ``"linear"``, ``"circular"`` or ``"blend"``.
    constraint_matrix : correct predictions with the inter-marker distance bounds.
    backlog : frames of history kept (default 30, the paper's); samples are ``(backlog - 1) // 2`` apart.
    threshold_cm : pairs whose largest minus smallest seen distance exceeds this are not rigid (cm).
    iterations : rounds of the constraint correction per frame.
    initial : ``[M, 3]`` cm, where to put a marker missing before it was ever seen (NaN rows: unknown).

    Example
    -------
    >>> ex = Extrapolator(labels, fps=120.0, constraint_matrix=True)
    >>> filled = ex.push(frame_positions, visible)   # [M, 3] cm, [M] bool -> [M, 3] cm
    """

    def __init__(
        self,
        labels: Sequence[str],
        fps: float,
        mode: str = "blend",
        constraint_matrix: bool = False,
        backlog: int = 30,
        threshold_cm: float = 10.0,
        iterations: int = 3,
        initial: np.ndarray | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        if int(backlog) < 3:
            raise ValueError(f"backlog must be at least 3 frames, got {backlog}")
        self.labels = tuple(labels)
        n = len(self.labels)
        self.fps = float(fps)
        self.mode = mode
        self.constraint_matrix = bool(constraint_matrix)
        self.threshold_cm = float(threshold_cm)
        self.iterations = int(iterations)
        self.spacing = (int(backlog) - 1) // 2
        self._length = 2 * self.spacing + 1
        self._ring = np.zeros((self._length, n, 3))
        self._ptr = 0
        self._history = np.zeros(n, dtype=int)  # frames with a value since first seen, capped at _length
        self._seen = np.zeros(n, dtype=bool)
        self._initial = np.full((n, 3), np.nan) if initial is None else np.array(initial, dtype=np.float64)
        if self._initial.shape != (n, 3):
            raise ValueError(f"initial must be [{n}, 3], got {self._initial.shape}")
        self.dist_min = np.full((n, n), np.inf)  # cm
        self.dist_max = np.full((n, n), -np.inf)  # cm

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    def _check(self, positions: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.array(positions, dtype=np.float64)
        vis = np.asarray(visible, dtype=bool)
        if x.shape != (self.n_markers, 3) or vis.shape != (self.n_markers,):
            raise ValueError(
                f"expected positions [{self.n_markers}, 3] and visible [{self.n_markers}], "
                f"got {x.shape} and {vis.shape}"
            )
        vis = vis & np.isfinite(x).all(axis=1)
        x[~vis] = np.nan
        return x, vis

    def _update_constraints(self, points: np.ndarray) -> None:
        """Widen the distance bounds with ``points [K, M, 3]`` (NaN = not visible; NaN pairs are skipped)."""
        diff = points[:, :, None, :] - points[:, None, :, :]
        dist = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
        self.dist_min = np.fmin(self.dist_min, np.fmin.reduce(dist, axis=0))
        self.dist_max = np.fmax(self.dist_max, np.fmax.reduce(dist, axis=0))

    def _advance(self, out: np.ndarray, vis: np.ndarray) -> None:
        self._ptr = (self._ptr + 1) % self._length
        self._ring[self._ptr] = out
        self._seen |= vis
        self._history[self._seen] = np.minimum(self._history[self._seen] + 1, self._length)

    def warm_up(self, points: np.ndarray) -> None:
        """Feed a block of fully visible frames ``[T, M, 3]`` (cm) at once.

        Same state as pushing them one by one (nothing is missing, so nothing is predicted), at a fraction
        of the cost: for calibration recordings or the complete stretches of an offline clip.
        """
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 3 or pts.shape[1:] != (self.n_markers, 3):
            raise ValueError(f"expected points [T, {self.n_markers}, 3], got {pts.shape}")
        bad = ~np.isfinite(pts).all(axis=(1, 2))
        if bad.any():
            raise ValueError(f"warm_up needs every marker visible; frame {int(np.argmax(bad))} has a missing one")
        if self.constraint_matrix:
            for start in range(0, len(pts), _WARM_UP_CHUNK):
                self._update_constraints(pts[start : start + _WARM_UP_CHUNK])
        everyone = np.ones(self.n_markers, dtype=bool)
        for frame in pts[-self._length :]:
            self._advance(frame, everyone)
        self._history = np.minimum(self._history + max(0, len(pts) - self._length), self._length)

    def push(self, positions: np.ndarray, visible: np.ndarray) -> np.ndarray:
        """Take one frame, return it with every missing marker filled.

        Parameters
        ----------
        positions : ``[M, 3]`` cm; values of markers not visible are ignored (NaN allowed).
        visible : ``[M]`` bool; a visible marker with a non-finite coordinate counts as missing.

        Returns
        -------
        ``[M, 3]`` cm: visible markers unchanged, missing ones predicted; never NaN.
        """
        x, vis = self._check(positions, visible)
        if self.constraint_matrix:
            self._update_constraints(x[None])
        miss = np.flatnonzero(~vis)
        if miss.size:
            seen = self._seen[miss]
            out_miss = self._ring[self._ptr, miss]
            ready = seen & (self._history[miss] >= self._length)
            if self.mode != "hold" and ready.any():
                idx = miss[ready]
                ages = (self._ptr - np.arange(self._length)) % self._length
                past = self._ring[np.ix_(ages, idx)]
                out_miss[ready] = predict_next(past, 1.0 / self.fps, self.spacing, self.mode)
            x[miss] = out_miss
            x[miss[~seen]] = np.nan
            if self.constraint_matrix and seen.any():
                self._correct(x, vis, miss[seen])
            if not seen.all():
                self._place_unseen(x, miss[~seen])
        self._advance(x, vis)
        return x

    def _correct(self, x: np.ndarray, vis: np.ndarray, rows: np.ndarray) -> None:
        """Move the predicted markers ``rows`` of ``x [M, 3]`` (in place) toward their rigid distance bounds."""
        lo, hi = self.dist_min[rows], self.dist_max[rows]
        rigid = np.isfinite(lo) & (hi - lo <= self.threshold_cm)
        weight = np.where(vis, 1.0, 0.5)
        for _ in range(self.iterations):
            diff = x[rows][:, None, :] - x[None, :, :]
            dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
            delta = np.clip(dist, lo, hi) - dist
            active = rigid & (dist > 0) & (delta != 0)
            if not active.any():
                return
            scale = np.where(active, weight * delta / np.where(active, dist, 1.0), 0.0)
            step = np.einsum("ij,ijk->ik", scale, np.where(active[..., None], diff, 0.0))
            x[rows] += step / np.maximum(active.sum(axis=1), 1)[:, None]

    def _place_unseen(self, x: np.ndarray, rows: np.ndarray) -> None:
        """Markers never seen: ``initial`` if known, else the centroid of the markers with a value."""
        known = np.isfinite(x).all(axis=1)
        centroid = x[known].mean(axis=0) if known.any() else np.zeros(3)
        init = self._initial[rows]
        x[rows] = np.where(np.isfinite(init).all(axis=1)[:, None], init, centroid)


def extrapolate(
    markers: Markers,
    mode: str = "blend",
    constraint_matrix: bool = False,
    backlog: int = 30,
    threshold_cm: float = 10.0,
    iterations: int = 3,
) -> np.ndarray:
    """Fill every missing sample of ``markers`` causally, as the streaming :class:`Extrapolator` would.

    Parameters are those of :class:`Extrapolator`. A gap at the start of the clip (no past at all) takes the
    marker's first visible value; a marker never visible takes the centroid of the others per frame.
    Stretches where every marker is visible go through ``warm_up`` (same result as ``push``, faster).

    Returns
    -------
    ``[T, M, 3]`` cm: visible samples unchanged, missing ones predicted from the past only; never NaN.
    """
    pts = markers.points
    vis = markers.visible & np.isfinite(pts).all(axis=2)
    first = np.argmax(vis, axis=0)
    initial = np.where(vis.any(axis=0)[:, None], pts[first, np.arange(markers.n_markers)], np.nan)
    ex = Extrapolator(markers.labels, markers.fps, mode, constraint_matrix, backlog, threshold_cm, iterations, initial)
    out = np.empty_like(pts)
    complete = vis.all(axis=1)
    # Runs of frames with the same completeness: [start, stop) pairs.
    edges = np.flatnonzero(np.diff(complete.astype(np.int8))) + 1
    bounds = np.concatenate([[0], edges, [len(pts)]])
    for start, stop in zip(bounds[:-1], bounds[1:]):
        if complete[start]:
            ex.warm_up(pts[start:stop])
            out[start:stop] = pts[start:stop]
            continue
        for t in range(start, stop):
            out[t] = ex.push(pts[t], vis[t])
    return out


def _points_method(mode: str, constraint_matrix: bool, **options: float) -> PointsClean:
    def clean(noisy: Markers) -> np.ndarray:
        return extrapolate(noisy, mode, constraint_matrix, **options)

    return clean


@register("hold", "points", help="hold the last value of a missing marker (streaming, causal)")
def _hold(context: MethodContext) -> PointsClean:
    return _points_method("hold", False)


@register("extrapolate-linear", "points", help="streaming linear extrapolation from the marker's own past")
def _linear(context: MethodContext, backlog: int = 30) -> PointsClean:
    return _points_method("linear", False, backlog=backlog)


@register("extrapolate-circular", "points", help="streaming circular extrapolation (linear where no circle fits)")
def _circular(context: MethodContext, backlog: int = 30) -> PointsClean:
    return _points_method("circular", False, backlog=backlog)


@register("extrapolate", "points", help="streaming linear/circular extrapolation blended by the matching factor")
def _blend(context: MethodContext, backlog: int = 30) -> PointsClean:
    return _points_method("blend", False, backlog=backlog)


@register(
    "extrapolate+cm",
    "points",
    help="blended extrapolation corrected by the inter-marker distance constraint matrix (threshold_cm=10)",
)
def _blend_cm(
    context: MethodContext, backlog: int = 30, threshold_cm: float = 10.0, iterations: int = 3
) -> PointsClean:
    return _points_method("blend", True, backlog=backlog, threshold_cm=threshold_cm, iterations=iterations)
