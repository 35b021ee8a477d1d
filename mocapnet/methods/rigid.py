"""Rigid-body (relational) gap filling: carry a missing marker with three or more visible markers that stay
rigid with it — the "rigid body fill" of Vicon Nexus and Qualisys Track Manager.

For a gap ``[a, b)`` of marker ``i`` (frames ``a .. b-1`` missing):

1. **Partners.** Markers visible in every frame from ``a - 1`` to ``b`` (the gap and the measured frames at
   its edges) whose distance to ``i`` keeps a standard deviation of at most ``max_std_cm`` over the frames
   where both are measured (:func:`distance_spread`). The ``max_partners`` most rigid are used; at least
   ``min_partners`` (3) that are not collinear (their second singular value at least 1 cm).
2. **Transform.** For each edge frame ``r`` (``a - 1`` and/or ``b``), the rigid transform taking the
   partners' configuration at ``r`` to their configuration at each gap frame ``t`` (weighted Kabsch:
   least-squares rotation via SVD, reflection excluded) carries ``i``'s measured position at ``r`` to frame ``t``.
3. **Blend.** With both edges measured, the two carried tracks are blended linearly in time (weight of the
   ``b`` edge ``(t - a + 1) / (b - a + 1)``), so the fill meets the measured samples at both edges; a gap
   at the start or end of the take uses its one edge.

The fit residual (RMS distance between the partners and their carried reference configuration over the
gap, cm) measures how rigid the partners really stayed; it is returned with each fill.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mocapnet.fill import runs
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Markers

_SPREAD_FRAMES = 1000  # at most this many evenly spaced frames enter the distance spread
_MIN_TOGETHER = 10  # frames two markers must share for their distance spread to count
_MIN_SPREAD_CM = 1.0  # partners whose second singular value at an edge is smaller are collinear
_WEIGHT_FLOOR_CM = 0.5  # partner weights 1 / (spread² + floor²): no partner dominates on noise alone


def distance_stats(points: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Standard deviation, smallest and largest distance (cm) between every pair of markers over the frames
    where both are measured, each ``[M, M]`` (at most 1000 evenly spaced frames of ``points [T, M, 3]`` cm;
    NaN for pairs measured together in fewer than 10 frames)."""
    step = max(1, len(points) // _SPREAD_FRAMES)
    pts, vis = np.nan_to_num(points[::step]), visible[::step]
    n = vis.astype(np.float64)
    both = np.einsum("ti,tj->ij", n, n)
    total, total2 = np.zeros(both.shape), np.zeros(both.shape)
    low, high = np.full(both.shape, np.inf), np.full(both.shape, -np.inf)
    for t in range(len(pts)):  # one frame at a time keeps memory at [M, M]
        d = np.linalg.norm(pts[t, :, None] - pts[t, None], axis=-1)
        w = np.outer(n[t], n[t])
        total += w * d
        total2 += w * d * d
        seen = w > 0
        low = np.where(seen, np.minimum(low, d), low)
        high = np.where(seen, np.maximum(high, d), high)
    enough = both >= _MIN_TOGETHER
    safe = np.where(enough, both, 1.0)
    var = np.maximum(total2 / safe - (total / safe) ** 2, 0.0)
    return np.where(enough, np.sqrt(var), np.nan), np.where(enough, low, np.nan), np.where(enough, high, np.nan)


def distance_spread(points: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Standard deviation (cm) of the distance between every pair of markers over the frames where both are
    measured, ``[M, M]`` (see :func:`distance_stats`; 0 on the diagonal)."""
    return distance_stats(points, visible)[0]


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotations ``[..., 3, 3]`` and translations ``[..., 3]`` minimising ``Σ_k w_k |R s_k + d - t_k|²`` from
    point sets ``source [..., K, 3]`` to ``target [..., K, 3]`` (the leading axes broadcast: one source to many
    targets, or one pair per entry; proper rotations: reflections excluded; ``weights [K]`` default equal)."""
    w = np.ones(source.shape[-2]) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    src_c = np.einsum("k,...ki->...i", w, source)
    tgt_c = np.einsum("k,...ki->...i", w, target)
    h = np.einsum("k,...ki,...kj->...ij", w, source - src_c[..., None, :], target - tgt_c[..., None, :])
    u, _, vt = np.linalg.svd(h)
    v, ut = np.swapaxes(vt, -1, -2), np.swapaxes(u, -1, -2)
    d = np.sign(np.linalg.det(v @ ut))
    fix = np.ones(h.shape[:-1])
    fix[..., 2] = np.where(d == 0, 1.0, d)
    rot = v @ (fix[..., :, None] * ut)  # V diag(1, 1, d) Uᵀ
    return rot, tgt_c - np.einsum("...ij,...j->...i", rot, src_c)


@dataclass(frozen=True)
class RigidFill:
    """A rigid-body fill of one gap: ``points [b - a, 3]`` cm, the partner markers used, the RMS fit
    residual of the partners over the gap (cm)."""

    points: np.ndarray
    partners: tuple[int, ...]
    residual_cm: float


def measured_edges(visible: np.ndarray, marker: int, start: int, stop: int) -> list[int]:
    """The frames ``start - 1`` and ``stop`` (the edges of a gap ``[start, stop)``) that exist in
    ``visible [T, M]`` and where ``marker`` is measured."""
    return [r for r in (start - 1, stop) if 0 <= r < len(visible) and visible[r, marker]]


def rigid_partners(
    visible: np.ndarray,
    spread: np.ndarray,
    marker: int,
    start: int,
    stop: int,
    max_std_cm: float = 2.0,
    max_partners: int = 6,
) -> np.ndarray:
    """Indices of the markers that stay rigid with ``marker`` (distance spread ≤ ``max_std_cm``) and are
    visible in every frame from ``start`` to ``stop - 1`` and at the edges where ``marker`` is measured,
    most rigid first."""
    edges = measured_edges(visible, marker, start, stop)
    lo, hi = min([start, *edges]), max([stop - 1, *edges]) + 1
    through = visible[lo:hi].all(axis=0)
    through[marker] = False
    row = spread[marker]
    ok = through & np.isfinite(row) & (row <= max_std_cm)
    idx = np.flatnonzero(ok)
    return idx[np.argsort(row[idx], kind="stable")][:max_partners]


def rigid_reach(
    visible: np.ndarray, spread: np.ndarray, marker: int, edge: int, direction: int, max_std_cm: float = 2.0
) -> int:
    """How many frames past the measured frame ``edge`` (``direction`` +1: later, -1: earlier) at least three
    rigid partners of ``marker`` (spread ≤ ``max_std_cm``) stay visible together with ``edge`` (0 if none)."""
    row = spread[marker]
    ok = np.isfinite(row) & (row <= max_std_cm) & visible[edge]
    ok[marker] = False
    if ok.sum() < 3:
        return 0
    ahead = visible[edge + direction :: direction] if direction > 0 else visible[edge - 1 :: -1]
    lost = ~ahead[:, ok]  # [frames past the edge, partners]
    first_lost = np.where(lost.any(axis=0), lost.argmax(axis=0), len(ahead))
    return int(np.sort(first_lost)[-3])


def _carry(
    points: np.ndarray, marker: int, partners: np.ndarray, weights: np.ndarray, edges: list[int], start: int, stop: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """Carry ``marker`` from each measured edge with ``partners`` (weighted Kabsch per gap frame) and blend.
    Returns the track ``[L, 3]`` and each partner's RMS deviation from its carried reference position ``[K]``
    (cm, the worse of the edges), or None when the partners are collinear at an edge."""
    tracks, deviations = [], []
    frames = points[start:stop][:, partners]  # [L, K, 3]
    for r in edges:
        ref = points[r, partners]
        sv = np.linalg.svd(ref - ref.mean(axis=0), compute_uv=False)
        if sv[1] < _MIN_SPREAD_CM:
            return None
        rot, shift = kabsch(ref, frames, weights)
        tracks.append(np.einsum("lij,j->li", rot, points[r, marker]) + shift)
        carried = np.einsum("lij,kj->lki", rot, ref) + shift[:, None]
        deviations.append(np.sqrt(np.mean(np.sum((carried - frames) ** 2, axis=-1), axis=0)))
    if len(tracks) == 1:
        return tracks[0], deviations[0]
    w = (np.arange(start, stop) - start + 1) / (stop - start + 1)
    return (1.0 - w)[:, None] * tracks[0] + w[:, None] * tracks[1], np.maximum(*deviations)


def rigid_fill_gap(
    points: np.ndarray,
    visible: np.ndarray,
    spread: np.ndarray,
    marker: int,
    start: int,
    stop: int,
    max_std_cm: float = 2.0,
    max_partners: int = 6,
    min_partners: int = 3,
    max_residual_cm: float = np.inf,
) -> RigidFill | None:
    """Rigid-body fill of ``points[start:stop, marker]`` (module docstring) from the edges ``start - 1`` and
    ``stop`` where the marker is measured (one edge: carried from it alone; a part of a longer gap may be
    filled this way); ``points [T, M, 3]`` cm, ``visible [T, M]``, ``spread [M, M]`` from
    :func:`distance_spread`. While the partners' RMS deviation from their rigid configuration exceeds
    ``max_residual_cm`` and more than ``min_partners`` remain, the partner that deviates most is dropped and
    the fit repeated. None when no edge is measured or fewer than ``min_partners`` non-collinear rigid
    partners are visible throughout."""
    edges = measured_edges(visible, marker, start, stop)
    if not edges:
        return None
    partners = rigid_partners(visible, spread, marker, start, stop, max_std_cm, max_partners)
    while len(partners) >= min_partners:
        # Weight each partner by how rigid it stayed: 1 / (spread² + (0.5 cm)²).
        weights = 1.0 / (spread[marker, partners] ** 2 + _WEIGHT_FLOOR_CM**2)
        got = _carry(points, marker, partners, weights, edges, start, stop)
        if got is None:
            return None
        track, deviation = got
        residual = float(np.sqrt(np.mean(deviation**2)))
        if residual <= max_residual_cm or len(partners) == min_partners:
            return RigidFill(track, tuple(int(p) for p in partners), residual)
        partners = np.delete(partners, int(np.argmax(deviation)))
    return None


def rigid_fill(points: np.ndarray, visible: np.ndarray, max_std_cm: float = 2.0, max_partners: int = 6) -> np.ndarray:
    """Rigid-body fill of every gap of ``points [T, M, 3]`` (cm; ``visible [T, M]``) that has three rigid
    partners visible throughout it. Returns ``[T, M, 3]`` cm: visible samples unchanged, NaN where no rigid
    fill was possible."""
    points = np.where(visible[..., None], points, np.nan)
    out = points.copy()
    spread = distance_spread(points, visible)
    for m in np.flatnonzero(~visible.all(axis=0)):
        for start, stop in runs(~visible[:, m]):
            fill = rigid_fill_gap(points, visible, spread, int(m), start, stop, max_std_cm, max_partners)
            if fill is not None:
                out[start:stop, m] = fill.points
    return out


@register(
    "rigid",
    "points",
    help="rigid-body fill from >= 3 visible markers rigid with the missing one (Kabsch, blended at both "
    "edges); gaps it cannot fill are interpolated linearly with a warning; options max_std_cm, max_partners",
)
def _rigid(context: MethodContext, max_std_cm: float = 2.0, max_partners: int = 6) -> Callable[[Markers], np.ndarray]:
    """``rigid`` for the harness: gaps without rigid partners are filled linearly with a warning."""
    from mocapnet.methods.pca import fill_remaining_linear

    def clean(noisy: Markers) -> np.ndarray:
        filled = rigid_fill(noisy.points, noisy.visible, max_std_cm, max_partners)
        return fill_remaining_linear(noisy, filled, "no three rigid partners visible through the gap")

    return clean
