"""The window search and fill shared by the joint-space (``knn_angles``) and point-space (``knn``) kNN
gap fillers: nearest windows of stored motion, per-neighbour continuity correction, blend with
interpolation. See the ``knn_angles`` module docstring for the method. Imports nothing of mocapnet."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

_KERNEL_EPS2 = 1e-6  # cm², ε² of the kernel weight 1 / (d² + ε²)
_ROW_BLOCK = 16  # query poses per matrix product (bounds memory to 16 · N / step floats)


def edge_seconds(missing: np.ndarray, fps: float) -> np.ndarray:
    """Seconds from every sample of ``missing [T, K]`` (True = missing) to the nearest observed sample of its
    column: 0 where observed, inf in a column with no observed sample."""
    n = len(missing)
    t = np.broadcast_to(np.arange(n)[:, None], missing.shape)
    last = np.maximum.accumulate(np.where(missing, -1, t), axis=0)
    after = np.minimum.accumulate(np.where(missing, n, t)[::-1], axis=0)[::-1]
    gap = np.minimum(np.where(last >= 0, t - last, np.inf), np.where(after < n, after - t, np.inf))
    return gap / fps


def blend_weight(spread: np.ndarray, seconds: np.ndarray, speed: float) -> np.ndarray:
    """Weight of the kNN estimate against interpolation, ``1 / (1 + (spread / (speed · seconds))²)``: 0 at an
    observed sample, towards 1 far from it where the neighbours agree (small ``spread``). ``speed`` (units
    of ``spread`` per second) is how fast interpolation's error is taken to grow with the distance
    ``seconds`` to the nearest observed sample. A NaN spread (no neighbours asked) counts as agreement."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.nan_to_num(spread, nan=0.0) / (speed * seconds)
    return 1.0 / (1.0 + np.nan_to_num(ratio, nan=0.0, posinf=np.inf) ** 2)


@dataclass
class FillStats:
    """What a window fill did: gaps (= windows searched), CPU seconds (``time.process_time``) in the
    search and in all, and per gap the neighbours' RMS feature distance per point (cm): over every weighted
    point (``distance``) and over the points missing in the gap only, where they are observed (the window's
    margins; ``limb_distance``, NaN when they are never observed)."""

    gaps: int = 0
    search_s: float = 0.0
    total_s: float = 0.0
    distance: list[float] = field(default_factory=list)
    limb_distance: list[float] = field(default_factory=list)


class Searcher:
    """Nearest *windows* of stored motion (``knn_angles`` module docstring, step 2): brute force over every
    ``step``-th start frame in float32, then the starts around the best ``shortlist · k`` of them are
    re-ranked exactly in float64 (so an exact match is found at distance 0).

    ``points [N, P, 3]`` (cm, normalised; NaN counts as 0, so mark such frames not allowed), ``clip [N]``
    (clip index of every frame, clips contiguous), ``name`` for error messages."""

    def __init__(self, points: np.ndarray, clip: np.ndarray, name: str = "database", step: int = 3, shortlist: int = 4):
        pts = np.asarray(points, dtype=np.float32)
        # No copy of a clean float32 database (the stored one): only the tables below add memory.
        self.points = np.nan_to_num(pts) if np.isnan(pts).any() else pts
        self.name = name
        self.step = step
        self.shortlist = shortlist
        self._tables: dict[int, np.ndarray] = {}
        starts = np.flatnonzero(np.diff(clip, prepend=-1) != 0)
        sizes = np.diff(np.append(starts, len(clip)))
        self.last = np.repeat(np.append(starts[1:], len(clip)) - 1, sizes)  # [N]: last frame of each one's clip

    def table(self, step: int) -> np.ndarray:
        """``[4P, N / step]`` float32, built on first use: coordinates and squared norms per point of every
        ``step``-th frame, so one matrix product gives ``-2 q·x + |x|²``. Only the steps asked for are kept
        (normally one: 1/3 of ``points``' size at the default step 3)."""
        if step not in self._tables:
            pts = self.points[::step]
            self._tables[step] = np.ascontiguousarray(
                np.concatenate([pts.reshape(len(pts), -1), (pts**2).sum(-1)], axis=1).T
            )
        return self._tables[step]

    def profiles(self, feats: np.ndarray, weights: np.ndarray, step: int) -> np.ndarray:
        """Weighted squared distances ``[F, N / step]`` (cm²) from query poses ``feats [F, P, 3]`` (cm) with
        point weights ``[F, P]`` to every ``step``-th database frame."""
        f = feats.astype(np.float32)
        w = weights.astype(np.float32)
        lhs = np.concatenate([(-2.0 * f * w[..., None]).reshape(len(f), -1), w], axis=1)
        out = lhs @ self.table(step)
        out += (w * (f**2).sum(-1)).sum(-1, keepdims=True)
        return out

    def windows(
        self, feats: np.ndarray, weights: np.ndarray, offsets: np.ndarray, length: int, allowed: np.ndarray, k: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` database windows of ``length`` frames nearest to the query window.

        ``feats [F, P, 3]`` (cm) and ``weights [F, P]``: the query's poses at frames ``offsets [F]`` of its
        window (multiples of a common stride). A database window starting at frame i is compared pose by
        pose with frames ``i + offsets``; it must lie in one clip with every frame allowed (``allowed [N]``).
        Returns squared distances ``[k]`` (cm², ascending) and start frames ``[k]``."""
        n_all = len(self.points)
        start = np.arange(n_all)
        barred = np.concatenate([[0], np.cumsum(~allowed)])  # a window is valid if none of its frames is barred
        valid = (self.last >= start + length - 1) & (barred[np.minimum(start + length, n_all)] == barred[start])
        stride = int(np.gcd.reduce(offsets)) if offsets.any() else 1
        step = max(s for s in range(1, self.step + 1) if stride % s == 0)
        coarse_valid = valid[::step]
        k = min(k, int(valid.sum()))
        if k == 0 or not coarse_valid.any():
            raise ValueError(f"knn {self.name}: no clip of {length} frames left to search")
        n = len(coarse_valid)
        total = np.zeros(n, dtype=np.float32)
        for block in np.array_split(np.arange(len(offsets)), -(-len(offsets) // _ROW_BLOCK)):
            prof = self.profiles(feats[block], weights[block], step)
            for row, off in zip(prof, offsets[block] // step):
                total[: n - off] += row[off:]
        total[~coarse_valid] = np.inf
        wide = min(self.shortlist * k, int(coarse_valid.sum()))
        coarse = np.argpartition(total, wide - 1)[:wide]
        # Each full-rate start belongs to the block of exactly one coarse start (no duplicates).
        idx = (coarse[:, None] * step + np.arange(-(step // 2), step - step // 2)).ravel()
        idx = idx[(idx >= 0) & (idx < n_all)]
        idx = idx[valid[idx]]
        d = np.zeros(len(idx))
        for f, off in enumerate(offsets):
            diff = self.points[idx + off].astype(np.float64) - feats[f]
            d += ((diff**2).sum(-1) * weights[f]).sum(-1)
        order = np.argsort(d)[:k]
        return d[order], idx[order]


@dataclass(frozen=True)
class WindowSettings:
    """Options of the window filler (``knn_angles`` module docstring): neighbours ``k``, window margin ``margin_s`` (s)
    observed on each side of the gap, weight gain of points near the gap ``near_gain``, blend speed
    ``speed`` (degrees or cm per second; None: no blend, the kNN estimate as is), ``offset`` (continuity)
    correction on/off, query pose rate ``query_hz``, and ``distance_gain`` (degrees or cm per cm): the
    neighbours' RMS feature distance per point times this is added (in quadrature) to their spread, so
    motion unlike anything in the database falls back to interpolation; ``own``: windows of the input's own
    fully observed frames compete with the database's (a repeated gesture, a gait cycle); ``fallback``:
    what the blend falls back to, ``lerp`` or (joint space only) ``pca`` (``knn_angles.pca_angles``);
    ``max_weight``: the largest weight the kNN estimate gets against the fallback (1: all of it where the
    neighbours agree far from the observed frames; 0.5: at most the mean of the two estimates);
    ``limb_distance``: the distance that ``distance_gain`` scales is measured on the missing points only, in
    the margins where they are observed (how well the neighbours match the missing limb itself), instead of
    on every point (joint space only); ``plateau_s``: the fallback's error is taken to stop growing this many
    seconds from the nearest observed frame (PCA's error does not grow like interpolation's; None: never);
    ``twist`` (joint space, fallback ``pca``): where the fallback's inverse kinematics takes the rotation that
    positions cannot fix (twist about a bone with one child) from: ``lerp`` (linear interpolation), ``knn``
    (the kNN estimate) or ``blend`` (the kNN/interpolation blend with the fill's own weight β);
    ``limb_gate`` (cm, joint space): a gap whose neighbours' limb distance exceeds this takes
    the fallback only (None: never); ``still_gate`` (joint space): the same where the limb distance exceeds
    this many times the limb's own motion in the window's margins (``knn_angles.limb_motion``; a limb that
    hardly moves is left to the fallback unless the neighbours match it that closely); ``gated_twist``
    (joint space): a gated gap's fallback still takes its twist (and the angles of end joints whose End Site
    coincides with them, which positions do not set either) from ``twist``'s reference (``blend``: with the
    weight β the gap would have had ungated) instead of from interpolation: the gate then swaps only what
    positions determine to PCA; ``short_chain`` (cm, joint space): in the PCA fallback, a joint whose
    subtree lies within this of it keeps the reference's angles for itself and its subtree
    (``knn_angles.short_chains``; None: never); ``pca_gate`` (joint space): a gap whose limb
    distance exceeds this many times PCA's own error at rebuilding the limb in the window's margins
    (``knn_angles.pca_margin_error``, cm) takes the fallback only: PCA is used where it reconstructs the
    observed margins better than the neighbours match them (None: never); ``fit_twist`` (joint space, fallback
    ``pca``): the fallback turns each joint with one bone about it (the upper arm, the thigh) so that its child's
    local rotation (the elbow's, the knee's) comes nearest the twist reference's, plus this weight times the same
    for the joint's own; no point moves (``knn_angles.fit_twists``; None: never); ``pca_pair`` (joint space):
    the fallback's positions are the mean of two PCA fills, with every known point and with the joints whose own
    rotation is missing hidden too, as the ``pca`` baseline does (``knn_angles.own_hidden``)."""

    k: int = 16
    margin_s: float = 0.3
    near_gain: float = 2.0
    speed: float | None = 60.0
    offset: bool = True
    query_hz: float = 10.0
    distance_gain: float = 0.0
    own: bool = True
    fallback: str = "lerp"
    max_weight: float = 1.0
    limb_distance: bool = False
    plateau_s: float | None = None
    twist: str = "lerp"
    limb_gate: float | None = None
    still_gate: float | None = None
    gated_twist: bool = False
    short_chain: float | None = None
    pca_gate: float | None = None
    fit_twist: float | None = None
    pca_pair: bool = False

    def __post_init__(self) -> None:
        gates = (self.plateau_s, self.limb_gate, self.still_gate, self.short_chain, self.pca_gate)
        flags = (self.offset, self.own, self.limb_distance, self.gated_twist, self.pca_pair)
        if not all(isinstance(v, bool) for v in flags):
            raise ValueError(
                f"knn: offset, own, limb_distance, gated_twist and pca_pair must be true or false; got {self}"
            )
        if not all(
            v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in (*gates, self.fit_twist)
        ):
            raise ValueError(
                "knn: plateau_s, limb_gate, still_gate, short_chain, pca_gate and fit_twist must be numbers or none; "
                f"got {self}"
            )
        positive = all(v is None or v > 0 for v in gates) and (self.fit_twist is None or self.fit_twist >= 0)
        choices = self.fallback in ("lerp", "pca") and self.twist in ("lerp", "knn", "blend")
        if self.k < 1 or not 0.0 <= self.max_weight <= 1.0 or not choices or not positive:
            raise ValueError(
                "knn: k must be >= 1, max_weight in [0, 1], fallback lerp or pca, twist lerp, knn or blend, "
                f"plateau_s, limb_gate, still_gate, short_chain and pca_gate > 0, fit_twist >= 0; got {self}"
            )


def estimate_run(
    base: np.ndarray,
    near: np.ndarray,
    kernel: np.ndarray,
    seconds: np.ndarray,
    lo: int,
    run: tuple[int, int],
    rms: float,
    settings: WindowSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kNN estimate of one channel's missing run ``[c0, c1)`` and its blend weight, from the neighbours'
    values ``near [S, k]`` at frames ``lo, lo + 1, …`` (kernel weights ``[k]``): with ``offset``, each
    neighbour contributes its deviation from its own straight line between the run's edge frames, added to
    ``base [T]`` (the interpolation). The weighted spread of the contributions and the neighbours' distance
    ``rms`` (cm) set the weight β (``blend_weight``, times ``max_weight``; 1 with ``speed`` None);
    ``seconds [T]``: distance to the nearest observed frame. Returns the run's frames ``t [n]``, the estimate
    ``[n]`` (units of ``near``) and β ``[n]``."""
    c0, c1 = run
    t = np.arange(c0, c1)
    vals = near[t - lo]
    edges = [f for f in (c0 - 1, c1) if 0 <= f < len(base)] if settings.offset else []
    if edges:
        at = near[np.array(edges) - lo]  # [E, k]
        line = at[0] if len(edges) == 1 else at[0] + (at[1] - at[0]) * ((t - edges[0]) / (edges[1] - edges[0]))[:, None]
        contrib = vals - line + base[t][:, None]
    else:
        contrib = vals
    est = contrib @ kernel
    if settings.speed is None:
        return t, est, np.ones(len(t))
    spread = np.sqrt(((contrib - est[:, None]) ** 2) @ kernel)
    d = seconds[t] if settings.plateau_s is None else np.minimum(seconds[t], settings.plateau_s)
    beta = settings.max_weight * blend_weight(np.hypot(spread, settings.distance_gain * rms), d, settings.speed)
    return t, est, beta


@dataclass(frozen=True)
class Neighbours:
    """The nearest windows of one gap (``search_gap``): the window starts at frame ``w0``; query poses at frames
    ``grid [F]`` with point weights ``weights [F, P]``; neighbours' squared distances ``d2 [k]`` (cm²), start
    frames ``starts [k]``, ``from_own [k]`` (start in the input) and normalised kernel weights ``kernel [k]``;
    ``rms`` their kernel-weighted RMS feature distance per weighted point and frame (cm); ``span``: the gap's
    frames with the observed frame on each side (clipped to the input), where the neighbours are read."""

    w0: int
    grid: np.ndarray
    weights: np.ndarray
    d2: np.ndarray
    starts: np.ndarray
    from_own: np.ndarray
    kernel: np.ndarray
    rms: float
    span: np.ndarray


def search_gap(
    searcher: Searcher,
    own: Searcher | None,
    feats: np.ndarray,
    visible: np.ndarray,
    gain: np.ndarray,
    gap: tuple[int, int],
    fps: float,
    settings: WindowSettings,
    allowed: np.ndarray,
    complete: np.ndarray,
    stats: FillStats,
) -> Neighbours:
    """The ``settings.k`` nearest windows of the gap ``[a, b)``: the gap plus ``margin_s`` on each side, one
    query pose every ``1 / query_hz`` s, from ``feats [T, P, 3]`` (cm) with point weights ``visible [T, P] ·
    gain [P]``, among the database's (``searcher``, frames ``allowed``) and, with ``own``, the input's own
    fully observed windows (frames ``complete``). Counts the gap, its search CPU time and distance in
    ``stats``."""
    a, b = gap
    n_t = len(feats)
    stride = max(1, int(round(fps / settings.query_hz)))
    margin = max(1, int(round(settings.margin_s * fps)))
    w0, w1 = max(0, a - margin), min(n_t, b + margin)
    grid = np.arange(w0, w1, stride)
    w = visible[grid] * gain
    t0 = time.process_time()
    d2, starts, from_own = neighbour_windows(
        searcher, own, feats[grid], w, grid - w0, w1 - w0, allowed, complete, settings.k
    )
    stats.search_s += time.process_time() - t0
    stats.gaps += 1
    kernel = 1.0 / (d2 + _KERNEL_EPS2)
    kernel /= kernel.sum()
    rms = float(np.sqrt((kernel * d2).sum() / w.sum()))
    stats.distance.append(rms)
    span = np.arange(max(a - 1, 0), min(b, n_t - 1) + 1)
    return Neighbours(w0, grid, w, d2, starts, from_own, kernel, rms, span)


def neighbour_windows(
    searcher: Searcher,
    own: Searcher | None,
    feats: np.ndarray,
    weights: np.ndarray,
    offsets: np.ndarray,
    length: int,
    allowed: np.ndarray,
    complete: np.ndarray,
    k: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``k`` nearest windows among the database's (``searcher``, frames ``allowed``) and, with ``own``, the
    input's own fully observed ones (frames ``complete``). Arguments as ``Searcher.windows``. Returns squared
    distances ``[k]`` (ascending), start frames ``[k]`` and ``from_own [k]`` (True: a start in the input)."""
    d2, starts = searcher.windows(feats, weights, offsets, length, allowed, k)
    from_own = np.zeros(len(d2), dtype=bool)
    if own is None or complete.sum() < length:
        return d2, starts, from_own
    try:
        d2_own, own_starts = own.windows(feats, weights, offsets, length, complete, k)
    except ValueError:  # no fully observed stretch as long as the window
        return d2, starts, from_own
    best = np.argsort(np.concatenate([d2, d2_own]))[:k]
    from_own = np.concatenate([from_own, np.ones(len(d2_own), dtype=bool)])[best]
    return np.concatenate([d2, d2_own])[best], np.concatenate([starts, own_starts])[best], from_own


def gather(
    stored: np.ndarray, own: np.ndarray, starts: np.ndarray, from_own: np.ndarray, rel: np.ndarray
) -> np.ndarray:
    """Values ``[S, k, ...]`` of the neighbour windows at frames ``rel [S]`` of each window: rows of ``stored``
    (database) or ``own`` (the input) as ``from_own`` says."""
    rows = starts[None, :] + rel[:, None]
    out = np.empty(rows.shape + stored.shape[1:])
    out[:, ~from_own] = stored[rows[:, ~from_own]]
    out[:, from_own] = own[rows[:, from_own]]
    return out
