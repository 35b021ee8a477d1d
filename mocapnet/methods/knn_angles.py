"""kNN gap filling of BVH motion in joint space: the missing rotation channels are taken from the k most
similar stretches of motion in a large clean database (``knn_database``), corrected for continuity and
blended with linear interpolation.

For every *gap* (maximal run of frames in which some scored channel is missing):

1. **Features.** Each frame's joint and End Site positions on the database's reference skeleton,
   normalised for root position, heading and bone lengths (``Reference.points``), missing channels
   linearly interpolated first. A point counts only where none of its ancestors' rotations is missing.
   Points near the missing joints weigh more: ``1 + near_gain / hops`` (hops = tree distance to the nearest
   missing joint).
2. **Search: whole windows, stacked over time.** The query is the gap plus ``margin_s`` of observed motion
   on each side, one pose every ``1 / query_hz`` s (after Krüger et al. 2010's stacked poses t − Δ, t,
   t + Δ, extended to the whole window). A database window of the same length is compared pose by pose
   (sum of weighted squared distances), so a neighbour must match the missing limb where it is still
   observed before and after the gap, and the rest of the body throughout. Exact k nearest windows by
   brute force: float32 matrix products (``|q|² − 2 q·x + |x|²``) against every third start frame, then
   float64 re-ranking of the frames around the best ones. Windows never cross clip boundaries; clips
   named like the input (and those in ``exclude``) are left out.
3. **Estimate with offset (continuity) correction.** Kernel weights ``1 / (d² + ε²)``. For each channel's
   own missing run, each neighbour contributes its deviation from its own straight line between the run's
   edge frames, added to the linear interpolation of the observed edges (one edge only: its offset). The
   weighted mean is the estimate; the weighted spread of the contributions (degrees) is kept.
4. **Blend.** ``out = lerp + β (knn − lerp)`` with ``β = 1 / (1 + (σ / (speed · d))²)``, d (s) the
   distance to the nearest observed frame of that channel and ``σ² = spread² + (distance_gain · rms)²``
   (rms: the neighbours' feature distance per point, cm): interpolation next to the observed frames, where
   the neighbours disagree, or where nothing in the database is close; the database where they agree.
   With the truth in the database σ = 0 and the fill is exact.

Observed samples and unscored channels are never changed; missing unscored channels are interpolated.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mocapnet.methods import knn_database  # a module import: knn_database and knn import each other
from mocapnet.methods.baselines import lerp_fill
from mocapnet.methods.knn import _runs, blend_weight, edge_seconds
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Motion, Skeleton

_KERNEL_EPS2 = 1e-6  # cm², ε² of the kernel weight 1 / (d² + ε²)
_ROW_BLOCK = 16  # query frames per block (bounds memory to about 2 · 16 · N floats)


def wrap(deg: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-180, 180) degrees."""
    return (deg + 180.0) % 360.0 - 180.0


def point_parents(skeleton: Skeleton) -> np.ndarray:
    """Parent joint of every point of ``point_labels`` (joints, then End Sites), ``[P]`` (-1 for the root)."""
    return np.array(list(skeleton.parents) + list(skeleton.end_parents), dtype=int)


def points_visible(skeleton: Skeleton, joint_missing: np.ndarray) -> np.ndarray:
    """``[T, P]``: a point's position is known where no strict ancestor joint has a missing rotation."""
    upstream = np.zeros_like(joint_missing)  # any ancestor-or-self missing
    for j, p in enumerate(skeleton.parents):
        upstream[:, j] = joint_missing[:, j] | (upstream[:, p] if p >= 0 else False)
    parents = point_parents(skeleton)
    out = np.ones((joint_missing.shape[0], len(parents)), dtype=bool)
    for i, p in enumerate(parents):
        if p >= 0:
            out[:, i] = ~upstream[:, p]
    return out


def hop_distances(skeleton: Skeleton, joints: Iterable[int]) -> np.ndarray:
    """Tree distance ``[P]`` (edges) from every point to the nearest of ``joints``."""
    parents = point_parents(skeleton)
    n = len(parents)
    adj: list[list[int]] = [[] for _ in range(n)]
    for i, p in enumerate(parents):
        if p >= 0:
            adj[i].append(p)
            adj[p].append(i)
    dist = np.full(n, np.inf)
    frontier = list(joints)
    dist[frontier] = 0
    while frontier:
        nxt = []
        for i in frontier:
            for j in adj[i]:
                if dist[j] == np.inf:
                    dist[j] = dist[i] + 1
                    nxt.append(j)
        frontier = nxt
    return dist


@dataclass
class FillStats:
    """What ``fill_angles`` did: gaps (= windows searched), CPU seconds (``time.process_time``) in the
    search and in all, and per gap the neighbours' RMS feature distance per point (cm)."""

    gaps: int = 0
    search_s: float = 0.0
    total_s: float = 0.0
    distance: list[float] = field(default_factory=list)


class Searcher:
    """Nearest *windows* of a ``SkeletonDatabase`` (module docstring, step 2): brute force over every
    ``step``-th start frame in float32, then the starts around the best ``shortlist · k`` of them are
    re-ranked exactly in float64 (so an exact match is found at distance 0)."""

    def __init__(self, db: knn_database.SkeletonDatabase, step: int = 3, shortlist: int = 4):
        self.db = db
        self.step = step
        self.shortlist = shortlist
        pts = db.points.astype(np.float32)
        # [3P + P, N]: coordinates and squared norms per point, so one product gives -2 q·x + |x|².
        self.table = np.concatenate([pts.reshape(len(pts), -1), (pts**2).sum(-1)], axis=1).T
        self._coarse: dict[int, np.ndarray] = {}
        starts = np.flatnonzero(np.diff(db.clip, prepend=-1) != 0)
        sizes = np.diff(np.append(starts, len(db.clip)))
        self.last = np.repeat(np.append(starts[1:], len(db.clip)) - 1, sizes)  # [N]: last frame of each one's clip

    def profiles(self, feats: np.ndarray, weights: np.ndarray, step: int) -> np.ndarray:
        """Weighted squared distances ``[F, N / step]`` (cm²) from query poses ``feats [F, P, 3]`` (cm) with
        point weights ``[F, P]`` to every ``step``-th database frame."""
        if step not in self._coarse:
            self._coarse[step] = np.ascontiguousarray(self.table[:, ::step])
        f = feats.astype(np.float32)
        w = weights.astype(np.float32)
        lhs = np.concatenate([(-2.0 * f * w[..., None]).reshape(len(f), -1), w], axis=1)
        out = lhs @ self._coarse[step]
        out += (w * (f**2).sum(-1)).sum(-1, keepdims=True)
        return out

    def windows(
        self, feats: np.ndarray, weights: np.ndarray, offsets: np.ndarray, length: int, allowed: np.ndarray, k: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` database windows of ``length`` frames nearest to the query window.

        ``feats [F, P, 3]`` (cm) and ``weights [F, P]``: the query's poses at frames ``offsets [F]`` of its
        window (multiples of a common stride). A database window starting at frame i is compared pose by
        pose with frames ``i + offsets``; it must lie in one allowed clip (``allowed [N]``). Returns squared
        distances ``[k]`` (cm², ascending) and start frames ``[k]``."""
        n_all = self.table.shape[1]
        valid = allowed & (self.last >= np.arange(n_all) + length - 1)
        stride = int(np.gcd.reduce(offsets)) if offsets.any() else 1
        step = max(s for s in range(1, self.step + 1) if stride % s == 0)
        coarse_valid = valid[::step]
        k = min(k, int(valid.sum()))
        if k == 0 or not coarse_valid.any():
            raise ValueError(f"knn database {self.db.describe()}: no clip of {length} frames left to search")
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
            diff = self.db.points[idx + off].astype(np.float64) - feats[f]
            d += ((diff**2).sum(-1) * weights[f]).sum(-1)
        order = np.argsort(d)[:k]
        return d[order], idx[order]


@dataclass(frozen=True)
class AngleSettings:
    """Options of ``fill_angles`` (module docstring): neighbours ``k``, window margin ``margin_s`` (s)
    observed on each side of the gap, weight gain of points near the gap ``near_gain``, blend speed
    ``speed`` (degrees per second; None: no blend, the kNN estimate as is), ``offset`` (continuity)
    correction on/off, query pose rate ``query_hz``, and ``distance_gain`` (degrees per cm): the neighbours'
    RMS feature distance per point times this is added (in quadrature) to their spread, so motion unlike
    anything in the database falls back to interpolation."""

    k: int = 16
    margin_s: float = 0.3
    near_gain: float = 2.0
    speed: float | None = 60.0
    offset: bool = True
    query_hz: float = 10.0
    distance_gain: float = 0.0


def fill_angles(
    motion: Motion,
    mask: np.ndarray,
    db: knn_database.SkeletonDatabase,
    settings: AngleSettings = AngleSettings(),
    exclude: Iterable[str] = (),
    searcher: Searcher | None = None,
) -> tuple[np.ndarray, FillStats]:
    """Fill the masked channels of ``motion.channels [T, C]`` (degrees; ``mask [T, C]`` True = missing)
    from ``db`` (module docstring). Returns channels ``[T, C]`` (observed samples unchanged) and stats.

    Raises ValueError naming the motion when its skeleton does not match the database's."""
    t_start = time.process_time()
    sk = motion.skeleton
    db.check(sk, motion.name)
    searcher = searcher or Searcher(db)
    stats = FillStats()
    base = lerp_fill(motion.channels, mask)
    out = base.copy()
    scored_cols = np.flatnonzero(sk.scored_mask)
    smask = mask[:, scored_cols]
    if not smask.any():
        return out, stats
    joint_missing = np.stack([mask[:, sk.joint_channels(j)].any(axis=1) for j in range(sk.n_joints)], axis=1)
    weights = points_visible(sk, joint_missing).astype(np.float32)
    feats = db.reference.points(sk, base, motion.fps, motion.name)
    skip = set(exclude) | {motion.name}
    allowed = np.array([n not in skip for n in db.names])[db.clip]
    stride = max(1, int(round(motion.fps / settings.query_hz)))
    margin = max(1, int(round(settings.margin_s * motion.fps)))
    seconds = edge_seconds(mask, motion.fps)
    n_t = motion.n_frames
    for a, b in _runs(smask.any(axis=1)):
        stats.gaps += 1
        unknown = np.flatnonzero(smask[a:b].any(axis=0))  # indices into scored_cols
        gain = 1.0 + settings.near_gain / np.maximum(hop_distances(sk, np.flatnonzero(joint_missing[a:b].any(0))), 1)
        w0, w1 = max(0, a - margin), min(n_t, b + margin)
        grid = np.arange(w0, w1, stride)
        w = weights[grid] * gain
        t0 = time.process_time()
        d2, starts = searcher.windows(feats[grid], w, grid - w0, w1 - w0, allowed, settings.k)
        stats.search_s += time.process_time() - t0
        kernel = 1.0 / (d2 + _KERNEL_EPS2)
        kernel /= kernel.sum()
        rms = float(np.sqrt((kernel * d2).sum() / w.sum()))  # cm per weighted point and frame
        stats.distance.append(rms)
        lo, hi = max(a - 1, 0), min(b, n_t - 1)
        span = np.arange(lo, hi + 1)
        traj = db.channels[starts[None, :] + (span - w0)[:, None]][:, :, unknown]  # [S, k, U]
        for u, c in enumerate(scored_cols[unknown]):
            near = base[span, c][:, None] + wrap(traj[:, :, u] - base[span, c][:, None])  # [S, k] degrees
            for c0, c1 in _runs(mask[lo : hi + 1, c]):
                _fill_run(out[:, c], base[:, c], near, kernel, seconds[:, c], lo, (c0 + lo, c1 + lo), rms, settings)
    out[~mask] = motion.channels[~mask]
    stats.total_s = time.process_time() - t_start
    return out, stats


def _fill_run(
    out: np.ndarray,
    base: np.ndarray,
    near: np.ndarray,
    kernel: np.ndarray,
    seconds: np.ndarray,
    lo: int,
    run: tuple[int, int],
    rms: float,
    settings: AngleSettings,
) -> None:
    """Fill one channel's missing run ``[c0, c1)`` of ``out [T]`` (degrees, in place) from the neighbours'
    values ``near [S, k]`` at frames ``lo, lo + 1, …`` (kernel weights ``[k]``): with ``offset``, each
    neighbour contributes its deviation from its own straight line between the run's edge frames, added
    to ``base`` (the interpolation); the weighted spread of the contributions and the neighbours' distance
    ``rms`` (cm) set the blend weight. ``seconds [T]``: distance to the nearest observed frame."""
    c0, c1 = run
    t = np.arange(c0, c1)
    vals = near[t - lo]
    edges = [f for f in (c0 - 1, c1) if 0 <= f < len(out)] if settings.offset else []
    if edges:
        at = near[np.array(edges) - lo]  # [E, k]
        line = at[0] if len(edges) == 1 else at[0] + (at[1] - at[0]) * ((t - edges[0]) / (edges[1] - edges[0]))[:, None]
        contrib = vals - line + base[t][:, None]
    else:
        contrib = vals
    est = contrib @ kernel
    spread = np.sqrt(((contrib - est[:, None]) ** 2) @ kernel)
    if settings.speed is None:
        out[t] = est
        return
    beta = blend_weight(np.hypot(spread, settings.distance_gain * rms), seconds[t], settings.speed)
    out[t] = base[t] + beta * (est - base[t])


def angle_filler(
    db: knn_database.SkeletonDatabase, settings: AngleSettings, exclude: Iterable[str] = ()
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """``clean(noisy, mask) -> [T, C]`` for the harness, with one searcher shared by every call."""
    searcher = Searcher(db)
    skip = tuple(exclude)

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return fill_angles(noisy, mask, db, settings, skip, searcher)[0]

    clean.database = db.describe()  # type: ignore[attr-defined]
    return clean


@register(
    "knn",
    "angles",
    help="kNN in joint space from a large clean database (default: the largest corpus of the skeleton, cached), "
    "offset-corrected and blended with lerp; options k, shift_s, near_gain, speed, offset, query_hz, "
    "distance_gain, database",
)
def _knn_angles(
    context: MethodContext, database: str | None = None, **options: Any
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """``knn`` for BVH data. The database is ``database`` (corpus name or folder of BVH files) or else the
    largest corpus of the input's skeleton under the data root, or else ``context.train``. When the
    database is the corpus being scored, only its training clips (``context.train``) are used; the clip
    being filled (same name) is always left out. The database is built on the first call."""
    settings = AngleSettings(**options)  # an unknown option is a TypeError, reported by build_method
    built: dict[tuple, Callable[[Motion, np.ndarray], np.ndarray]] = {}

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        key = noisy.skeleton.topology()
        if key not in built:
            corpus = database or knn_database.default_corpus(noisy.skeleton)
            if corpus is not None:
                db = knn_database.cached_database(corpus)
            elif context.train:
                db = knn_database.SkeletonDatabase.from_motions(
                    list(context.train), source=context.corpus or "training clips"
                )
            else:
                raise ValueError(
                    f"{noisy.name or 'motion'}: knn found no corpus of this skeleton; give database=<folder>"
                )
            exclude: list[str] = []
            if context.train and db.source == context.corpus:
                keep = {m.name for m in context.train}
                exclude = [n for n in db.names if n not in keep]
            built[key] = angle_filler(db, settings, exclude)
            clean.database = built[key].database  # type: ignore[attr-defined]
        return built[key](noisy, mask)

    return clean
