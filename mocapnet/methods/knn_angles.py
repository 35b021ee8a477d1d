"""kNN gap filling of BVH motion in joint space: the missing rotation channels are taken from the k most
similar frames of a large clean database (``knn_database``), then corrected for continuity and blended
with linear interpolation.

For every *gap* (maximal run of frames in which some scored channel is missing):

1. **Features.** Each frame's joint and End Site positions on the database's reference skeleton,
   normalised for root position, heading and bone lengths (``Reference.points``), missing channels
   linearly interpolated first. A point counts only where none of its ancestors' rotations is missing.
   Poses are stacked over time (frames t − Δ, t, t + Δ, after Krüger et al. 2010; Δ = ``shift_s``), so a
   frame next to the gap also sees the missing limb where it was still observed. Points near the missing
   joints weigh more: weight ``1 + near_gain / hops`` (hops = tree distance to the nearest missing joint).
2. **Search.** Exact k nearest neighbours by blocked brute force (``|q|² − 2 q·x + |x|²`` as float32
   matrix products over the whole database; a frame's stacked distance is the sum of its three shifted
   per-frame distances, never across clip boundaries). The query frames are every ``stride``-th frame of
   the gap (``query_hz``) plus the observed frames just before and after it; in between, each query frame's
   neighbours are followed forward (or back) in their own clips and the two estimates mixed linearly. Clips
   named like the input (and those in ``exclude``) are left out.
3. **Estimate.** Kernel-weighted mean (``1 / (d² + ε²)``) of the neighbours' channels, as wrapped
   differences from the interpolated value (so Euler wrap-around cannot split a mean); the neighbours'
   weighted spread (RMS, degrees) is kept per channel.
4. **Offset (continuity) correction.** For each channel's own missing run, the estimate is shifted by the
   difference between the observed value and the estimate at the frames just before and after the run,
   blended linearly across it (one side only: constant).
5. **Blend.** ``out = lerp + β (knn − lerp)`` with ``β = 1 / (1 + (spread / (speed · d))²)``, d (s) the
   distance to the nearest observed frame of that channel: interpolation where it is reliable (next to the
   observed frames) or where the neighbours disagree (large spread); the database where they agree. With
   the truth in the database the spread is 0 and the fill is exact.

Observed samples and unscored channels are never changed; missing unscored channels are interpolated.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from mocapnet.methods import knn_database  # a module import: knn_database and knn import each other
from mocapnet.methods.baselines import lerp_fill
from mocapnet.methods.knn import blend_weight, edge_seconds
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Motion, Skeleton

_KERNEL_EPS2 = 1e-6  # cm², ε² of the kernel weight 1 / (d² + ε²)
_ROW_BLOCK = 16  # query frames per block (bounds memory to about 2 · 16 · N floats)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True in a 1-D boolean array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


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
    """What ``fill_angles`` did: gaps, query frames, CPU seconds (``time.process_time``) in the search."""

    gaps: int = 0
    queries: int = 0
    search_s: float = 0.0
    total_s: float = 0.0
    spread: list[float] = field(default_factory=list)


class Searcher:
    """Brute-force k-NN over a ``SkeletonDatabase``'s normalised points (module docstring, step 2)."""

    def __init__(self, db: knn_database.SkeletonDatabase):
        self.db = db
        pts = db.points.astype(np.float32)
        # [N, 3P + P]: coordinates and squared norms per point, so one product gives -2 q·x + |x|².
        self.table = np.ascontiguousarray(np.concatenate([pts.reshape(len(pts), -1), (pts**2).sum(-1)], axis=1).T)
        self._same_clip: dict[int, np.ndarray] = {}
        starts = np.flatnonzero(np.diff(db.clip, prepend=-1) != 0)
        ends = np.append(starts[1:], len(db.clip)) - 1
        sizes = np.diff(np.append(starts, len(db.clip)))
        self.first, self.last = np.repeat(starts, sizes), np.repeat(ends, sizes)  # [N]: each frame's clip bounds

    def same_clip(self, shift: int) -> np.ndarray:
        """``[N]`` bool: frames i with i − shift and i + shift in the same clip as i."""
        if shift not in self._same_clip:
            clip = self.db.clip
            ok = np.zeros(len(clip), dtype=bool)
            mid = clip[shift:-shift]
            ok[shift:-shift] = (clip[: -2 * shift] == mid) & (clip[2 * shift :] == mid)
            self._same_clip[shift] = ok
        return self._same_clip[shift]

    def profiles(self, feats: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Weighted squared distances ``[F, N]`` (cm²) from query poses ``feats [F, P, 3]`` (cm) with point
        weights ``[F, P]`` to every database frame."""
        f = feats.astype(np.float32)
        w = weights.astype(np.float32)
        lhs = np.concatenate([(-2.0 * f * w[..., None]).reshape(len(f), -1), w], axis=1)
        out = lhs @ self.table
        out += (w * (f**2).sum(-1)).sum(-1, keepdims=True)
        return out

    def query(
        self, feats: np.ndarray, weights: np.ndarray, centre: np.ndarray, shift: int, allowed: np.ndarray, k: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """k nearest database frames of each query frame in time-stacked features.

        ``feats [T, P, 3]`` (cm) and ``weights [T, P]`` of the whole query clip; ``centre [R]``: the query
        frames (t − shift and t + shift are clamped to the clip). ``allowed [N]``. Returns squared distances
        ``[R, k]`` (cm², ascending) and database indices ``[R, k]``."""
        n = self.table.shape[1]
        valid = allowed & self.same_clip(shift)
        k = min(k, int(valid.sum()))
        if k == 0:
            raise ValueError(f"knn database {self.db.describe()}: no usable frame")
        last = len(feats) - 1
        dists, idxs = [], []
        for rows in np.array_split(centre, -(-len(centre) // _ROW_BLOCK)):
            frames = np.clip(rows[:, None] + np.array([-shift, 0, shift]), 0, last)
            uniq, inverse = np.unique(frames, return_inverse=True)
            prof = self.profiles(feats[uniq], weights[uniq])
            inverse = inverse.reshape(frames.shape)
            total = np.empty((len(rows), n), dtype=np.float32)
            total[:, :shift] = np.inf
            total[:, n - shift :] = np.inf
            body = total[:, shift : n - shift]
            np.add(prof[inverse[:, 0], : n - 2 * shift], prof[inverse[:, 1], shift : n - shift], out=body)
            body += prof[inverse[:, 2], 2 * shift :]
            total[:, ~valid] = np.inf
            wide = min(2 * k, int(valid.sum()))  # float32 shortlist, re-ranked in float64 below
            idx = np.argpartition(total, wide - 1, axis=1)[:, :wide]
            d = self._exact(feats, weights, frames, idx, shift)
            order = np.argsort(d, axis=1)[:, :k]
            dists.append(np.take_along_axis(d, order, axis=1))
            idxs.append(np.take_along_axis(idx, order, axis=1))
        return np.concatenate(dists), np.concatenate(idxs)

    def continued(
        self,
        idx: np.ndarray,
        kernel: np.ndarray,
        grid: np.ndarray,
        span: np.ndarray,
        unknown: np.ndarray,
        ref: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Estimate ``[S, U]`` (degrees) and spread ``[S, U]`` of the channels ``unknown`` (indices into the
        scored channels) at frames ``span [S]`` from the neighbours ``idx [R, k]`` (weights ``kernel``) of the
        query frames ``grid [R]``: between two query frames, each one's neighbours are followed forward or
        back in their own clip by the same number of frames, and the two estimates are mixed linearly. Means
        are wrapped differences from ``ref [S, U]`` (degrees)."""
        j = np.clip(np.searchsorted(grid, span, side="right") - 1, 0, max(len(grid) - 2, 0))
        nxt = np.minimum(j + 1, len(grid) - 1)
        gap = np.maximum(grid[nxt] - grid[j], 1)
        lam = np.clip((span - grid[j]) / gap, 0.0, 1.0)[:, None]
        sides = []
        for rows in (j, nxt):
            nb = np.clip(idx[rows] + (span - grid[rows])[:, None], self.first[idx[rows]], self.last[idx[rows]])
            diff = wrap(self.db.channels[nb][:, :, unknown] - ref[:, None])  # [S, k, U]
            w = kernel[rows][..., None]
            mean = (w * diff).sum(axis=1)
            sides.append((mean, np.sqrt((w * (diff - mean[:, None]) ** 2).sum(axis=1))))
        (m0, s0), (m1, s1) = sides
        return ref + (1 - lam) * m0 + lam * m1, (1 - lam) * s0 + lam * s1

    def _exact(self, feats: np.ndarray, weights: np.ndarray, frames: np.ndarray, idx: np.ndarray, shift: int):
        """Stacked squared distances ``[R, K]`` (cm², float64) of query frames ``frames [R, 3]`` to database
        frames ``idx [R, K]`` (the float32 products lose about 0.01 cm² to rounding; an exact match must
        get distance 0)."""
        out = np.zeros(idx.shape)
        for s, off in enumerate((-shift, 0, shift)):
            diff = self.db.points[idx + off].astype(np.float64) - feats[frames[:, s]][:, None]
            out += ((diff**2).sum(-1) * weights[frames[:, s]][:, None]).sum(-1)
        return out


@dataclass(frozen=True)
class AngleSettings:
    """Options of ``fill_angles`` (module docstring): neighbours ``k``, time shift ``shift_s`` (s), weight
    gain of points near the gap ``near_gain``, blend speed ``speed`` (degrees per second; None: no blend,
    the corrected kNN estimate as is), ``offset`` correction on/off, query rate ``query_hz``."""

    k: int = 32
    shift_s: float = 0.2
    near_gain: float = 2.0
    speed: float | None = 60.0
    offset: bool = True
    query_hz: float = 10.0


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
    visible = points_visible(sk, joint_missing)
    feats = db.reference.points(sk, base, motion.fps, motion.name)
    skip = set(exclude) | {motion.name}
    allowed = ~np.isin(np.arange(len(db.names)), [i for i, n in enumerate(db.names) if n in skip])[db.clip]
    stride = max(1, int(round(motion.fps / settings.query_hz)))
    shift = stride * max(1, int(round(settings.shift_s * motion.fps / stride)))  # shared profiles (see query)
    weights = visible.astype(np.float32)
    seconds = edge_seconds(mask, motion.fps)
    n_t = motion.n_frames
    for a, b in _runs(smask.any(axis=1)):
        stats.gaps += 1
        unknown = np.flatnonzero(smask[a:b].any(axis=0))  # indices into scored_cols
        missing_joints = np.flatnonzero(joint_missing[a:b].any(axis=0))
        gain = 1.0 + settings.near_gain / np.maximum(hop_distances(sk, missing_joints), 1.0)
        lo, hi = max(a - 1, 0), min(b, n_t - 1)
        grid = np.unique(np.concatenate([np.arange(lo, hi + 1, stride), [lo, hi]]))
        t0 = time.process_time()
        d2, idx = searcher.query(feats, weights * gain, grid, shift, allowed, settings.k)
        stats.search_s += time.process_time() - t0
        stats.queries += len(grid)
        kernel = 1.0 / (d2 + _KERNEL_EPS2)
        kernel /= kernel.sum(axis=1, keepdims=True)
        cols = scored_cols[unknown]
        span = np.arange(lo, hi + 1)
        est, sprd = searcher.continued(idx, kernel, grid, span, unknown, base[span][:, cols])
        stats.spread.append(float(sprd.mean()))
        for u, c in enumerate(cols):
            for c0, c1 in _runs(mask[lo : hi + 1, c]):
                _fill_run(out[:, c], base[:, c], est[:, u], sprd[:, u], seconds[:, c], lo, (c0 + lo, c1 + lo), settings)
    out[~mask] = motion.channels[~mask]
    stats.total_s = time.process_time() - t_start
    return out, stats


def _fill_run(
    out: np.ndarray,
    base: np.ndarray,
    est: np.ndarray,
    spread: np.ndarray,
    seconds: np.ndarray,
    lo: int,
    run: tuple[int, int],
    settings: AngleSettings,
) -> None:
    """Offset-correct and blend one channel's missing run ``[c0, c1)`` into ``out [T]`` (degrees, in place);
    ``est``/``spread`` cover frames ``lo, lo + 1, …``; ``seconds [T]`` to the nearest observed frame."""
    c0, c1 = run
    t = np.arange(c0, c1)
    e = est[t - lo]
    if settings.offset:
        known = [(f, wrap(base[f] - est[f - lo])) for f in (c0 - 1, c1) if 0 <= f < len(out)]
        if len(known) == 2:
            (f0, o0), (f1, o1) = known
            e = e + o0 + (o1 - o0) * (t - f0) / (f1 - f0)
        elif known:
            e = e + known[0][1]
    beta = 1.0 if settings.speed is None else blend_weight(spread[t - lo], seconds[t], settings.speed)
    out[t] = base[t] + beta * wrap(e - base[t])


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
    "offset-corrected and blended with lerp; options k, shift_s, near_gain, speed, offset, query_hz, database",
)
def _knn_angles(
    context: MethodContext,
    k: int = 32,
    shift_s: float = 0.2,
    near_gain: float = 2.0,
    speed: float | None = 60.0,
    offset: bool = True,
    query_hz: float = 10.0,
    database: str | None = None,
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """``knn`` for BVH data. The database is ``database`` (corpus name or folder of BVH files) or else the
    largest corpus of the input's skeleton under the data root, or else ``context.train``. When the
    database is the corpus being scored, only its training clips (``context.train``) are used; the clip
    being filled (same name) is always left out. The database is built on the first call."""
    settings = AngleSettings(k, shift_s, near_gain, speed, offset, query_hz)
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
