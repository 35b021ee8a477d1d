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
4. **Blend.** ``out = f + β (knn − f)`` with ``β = max_weight / (1 + (σ / (speed · d))²)``, d (s) the
   distance to the nearest observed frame of that channel (capped at ``plateau_s`` when set) and
   ``σ² = spread² + (distance_gain · rms)²``. rms is the neighbours' feature distance per point (cm): by
   default (``limb_distance``) measured on the missing limb's own points in the window's margins, where they
   are observed, which tells a neighbour that moves the limb otherwise apart from one that only matches
   the rest of the body. The fallback f is linear interpolation or (default) the clip's own PCA fill
   (Gløersen & Federolf on the joint positions, back to angles by IK, ``pca_angles``): f next to the
   observed frames, where the neighbours disagree, or where nothing in the database moves the limb alike
   (motion the database lacks); the database where they agree. Positions cannot fix a joint's twist about
   a bone with one child; the IK keeps the twist of its reference (``twist``): linear interpolation, the kNN
   estimate, or their blend with weight β (``blend``), and all the angles of an end joint whose End Site
   coincides with it (Bandai's head, hands and toes). With ``limb_gate``, a gap whose
   limb distance exceeds it gets β = 0 (f alone); with ``still_gate``, one whose limb distance exceeds that
   many times the limb's own motion in the margins (``limb_motion``); with ``pca_gate``, one whose limb
   distance exceeds that many times PCA's own error at rebuilding the limb in the margins, the limb hidden
   over the whole window (``pca_margin_error``). A gated gap's reference is
   interpolation, or with ``gated_twist`` still ``twist``'s (``blend``: with the β it would have had), so that
   the gate changes only what positions determine: f's joint positions are PCA's either way. With
   ``short_chain`` (cm), a joint whose subtree lies that close to it (Bandai at 15 cm: neck, head, hands,
   feet, toes) and its subtree keep the reference's angles instead (``short_chains``): positions a few cm
   apart set angles poorly. With ``fit_twist``, the fallback's joints with one bone (upper arm, thigh) are
   turned about it so that the child's bend (elbow, knee) comes nearest the reference's (``fit_twists``; no
   point moves); with ``pca_pair``, its positions are the mean of two PCA fills, with every known point and
   with the joints whose own rotation is missing hidden too (the ``pca`` baseline's view, ``own_hidden``).
   With the truth in the database σ = 0 and the fill is exact.

Observed samples and unscored channels are never changed; missing unscored channels are interpolated.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.fill import lerp_fill, runs
from mocapnet.kinematics import (
    inverse_kinematics,
    joint_positions,
    local_rotations,
    local_translations,
    matrix_to_euler,
    rotation_sequence,
    wrap_deg,
)
from mocapnet.methods.knn_database import SkeletonDatabase, cached_database, default_corpus
from mocapnet.methods.knn_window import (
    FillStats,
    Searcher,
    WindowSettings,
    edge_seconds,
    estimate_run,
    gather,
    search_gap,
)
from mocapnet.methods.pca import pca_fill
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Motion, Skeleton


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


# Joint-space defaults that differ from ``WindowSettings``'s, chosen on bandai2 fold-1 clips with and
# without their content label in the database (the second mimics motion the database lacks), by the rule
# of ``mocapnet.evaluate.knn_bench.tune_scores`` (benchmarks/results/knn_tuning.md, knn_tuning_plateau.md,
# knn_tuning_fallback.md for twist, gated_twist, short_chain and still_gate, knn_tuning_pair.md for the last three).
ANGLE_DEFAULTS: dict[str, Any] = {
    "fallback": "pca",
    "distance_gain": 6.0,
    "limb_distance": True,
    "speed": 120.0,
    "plateau_s": 0.5,
    "twist": "blend",
    "gated_twist": True,
    "short_chain": 15.0,
    "still_gate": 2.0,
    "pca_pair": True,
    "fit_twist": 1.0,
    "pca_gate": 3.0,
}


def short_chains(skeleton: Skeleton, max_cm: float) -> np.ndarray:
    """``[C]``: the channels of the joints whose whole subtree (descendant joints and End Sites) lies within
    ``max_cm`` of them, measured along the bones of the rest offsets (Bandai at 15 cm: neck, head, hands, feet
    and toes; Foot to Toes is 11.75 cm)."""
    parents = point_parents(skeleton)
    lengths = np.linalg.norm(np.concatenate([skeleton.offsets, skeleton.end_sites]), axis=1) * skeleton.cm_per_unit
    reach = np.zeros(len(parents))  # longest path (cm) from each point down to a point of its subtree
    for i in range(len(parents) - 1, 0, -1):  # children after their parents: joints in order, End Sites last
        reach[parents[i]] = max(reach[parents[i]], reach[i] + lengths[i])
    out = np.zeros(skeleton.n_channels, dtype=bool)
    for j in np.flatnonzero(reach[: skeleton.n_joints] <= max_cm):
        out[skeleton.joint_channels(j)] = True
    return out


def twist_axes(skeleton: Skeleton, channels: np.ndarray) -> list[tuple[int, int]]:
    """``(joint, child)`` for every joint whose only bone of non-zero length (local translations of
    ``channels [T, C]`` at the first frame, End Site offsets; as ``inverse_kinematics`` counts them) leads to a
    child joint: its twist about that bone moves no point. Context joints are left out (never filled)."""
    context = set(skeleton.context_joints)
    trans = local_translations(skeleton, channels[:1])[0]
    out = []
    for j in range(skeleton.n_joints):
        bones = [c for c in skeleton.children[j] if np.linalg.norm(trans[c]) > 1e-9]
        ends = [
            e for e, p in enumerate(skeleton.end_parents) if p == j and np.linalg.norm(skeleton.end_sites[e]) > 1e-9
        ]
        if j not in context and len(bones) == 1 and not ends:
            out.append((j, bones[0]))
    return out


def fit_twists(
    skeleton: Skeleton, channels: np.ndarray, reference: np.ndarray, change: np.ndarray, own_weight: float
) -> np.ndarray:
    """``channels [T, C]`` (degrees) with each ``twist_axes`` joint turned about its bone, and its child turned
    back, so that the child's local rotation comes nearest ``reference``'s (the elbow's or knee's bend in the
    reference's plane), plus ``own_weight`` × the same for the joint's own local rotation. No joint or End
    Site moves. Only frames where both joints' rotation channels are all in ``change [T, C]`` are touched,
    parents first. With ``a`` the bone's unit vector in the joint's frame, the angle θ maximises
    ``tr(Rot(a, θ)ᵀ M)`` with ``M = R_c R̂_cᵀ + w R_jᵀ R̂_j`` (R̂: the reference's local rotations):
    ``θ = atan2(a · vee(M), tr M − aᵀ M a)``."""
    out = channels.copy()
    rot = local_rotations(skeleton, channels)
    ref = local_rotations(skeleton, reference)
    trans = local_translations(skeleton, channels)
    for j, c in twist_axes(skeleton, channels):
        seq_j, cols_j = rotation_sequence(skeleton, j)
        seq_c, cols_c = rotation_sequence(skeleton, c)
        if not seq_j or not seq_c:
            continue
        sel = np.flatnonzero(change[:, cols_j].all(axis=1) & change[:, cols_c].all(axis=1))
        if not len(sel):
            continue
        axis = trans[sel, c] / np.linalg.norm(trans[sel, c], axis=1, keepdims=True)  # [S, 3]
        r_j, r_c = rot[sel, j], rot[sel, c]
        m = r_c @ np.swapaxes(ref[sel, c], 1, 2) + own_weight * np.swapaxes(r_j, 1, 2) @ ref[sel, j]
        vee = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1)
        along = np.einsum("ti,tij,tj->t", axis, m, axis)
        theta = np.arctan2((vee * axis).sum(1), np.trace(m, axis1=1, axis2=2) - along)
        turn = Rotation.from_rotvec(theta[:, None] * axis).as_matrix()
        rot[sel, j] = r_j @ turn
        rot[sel, c] = np.swapaxes(turn, 1, 2) @ r_c
        out[np.ix_(sel, cols_j)] = matrix_to_euler(rot[sel, j], seq_j, reference=channels[np.ix_(sel, cols_j)])
        out[np.ix_(sel, cols_c)] = matrix_to_euler(rot[sel, c], seq_c, reference=channels[np.ix_(sel, cols_c)])
    return out


def pca_angles(
    motion: Motion,
    mask: np.ndarray,
    base: np.ndarray,
    visible: np.ndarray,
    keep: np.ndarray | None = None,
    fit_twist: float | None = None,
    hidden: np.ndarray | None = None,
) -> np.ndarray:
    """``base [T, C]`` (degrees) with the masked samples replaced by the Gløersen & Federolf PCA fill of the
    joint and End Site positions (``visible [T, P]``), taken back to angles by ``inverse_kinematics`` (twist
    from ``base``); points PCA cannot rebuild keep ``base``'s positions, and channels ``keep [C]`` (whole
    subtrees, ``short_chains``) keep ``base``'s angles. With ``hidden [T, P]`` (points also hidden, e.g.
    ``own_hidden``), the IK's targets are the mean of the two fills, with ``visible`` and with ``visible &
    ~hidden``, where both rebuilt a point (else the one that did). A known point hidden in the second fill (the
    upper arm's position) thus gets the mean of its known position and PCA's estimate as its target, as the
    ``pca`` baseline gets PCA's estimate alone: the IK turns its parent (whose channels are not written) towards
    it, and the written angles of the joints below are relative to that turned frame. With ``fit_twist`` (the
    weight of a joint's own reference), ``fit_twists`` turns the joints with one bone about it towards
    ``base``'s bends."""
    ref = motion.with_channels(base)
    pos = joint_positions(ref, end_sites=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        filled = pca_fill(np.where(visible[..., None], pos, np.nan), visible)
        if hidden is not None and (visible & hidden).any():
            fewer = visible & ~hidden
            other = pca_fill(np.where(fewer[..., None], pos, np.nan), fewer)
            filled = np.where(np.isfinite(filled), np.where(np.isfinite(other), (filled + other) / 2, filled), other)
    out = base.copy()
    change = mask if keep is None else mask & ~keep[None]
    ik = inverse_kinematics(ref, np.where(np.isfinite(filled), filled, pos))
    if fit_twist is not None:
        ik = fit_twists(motion.skeleton, ik, base, change, fit_twist)
    out[change] = ik[change]
    return out


def own_hidden(skeleton: Skeleton, joint_missing: np.ndarray) -> np.ndarray:
    """``[T, P]``: the joints whose own rotation is missing (their positions are known where
    ``points_visible`` says so: the ``pca`` baseline of ``harness.evaluate_angles`` hides them anyway)."""
    out = np.zeros((len(joint_missing), len(point_parents(skeleton))), dtype=bool)
    out[:, : skeleton.n_joints] = joint_missing
    return out


def limb_rms(
    stored: np.ndarray,
    feats: np.ndarray,
    starts: np.ndarray,
    from_own: np.ndarray,
    grid: np.ndarray,
    w0: int,
    w: np.ndarray,
    kernel: np.ndarray,
    gap: tuple[int, int],
) -> float:
    """Kernel-weighted RMS distance (cm per weighted point and frame) between the query ``feats [T, P, 3]`` and
    its neighbour windows (``starts [k]``, ``from_own [k]``; points ``stored [N, P, 3]``) over the points
    missing somewhere in ``gap`` (the limb), on the window's grid frames ``grid`` (from ``w0``) where they
    are observed (weights ``w [F, P]``, 0 where missing). NaN when the limb is never observed there."""
    limb = limb_points(w, grid, gap)
    wl = w[:, limb]
    if wl.sum() == 0:
        return float("nan")
    near = gather(stored[:, limb], feats[:, limb], starts, from_own, grid - w0)  # [F, k, L, 3]
    d2 = (((near - feats[grid][:, None, limb]) ** 2).sum(-1) * wl[:, None]).sum(axis=(0, 2))  # [k]
    return float(np.sqrt((kernel * d2).sum() / wl.sum()))


def limb_points(w: np.ndarray, grid: np.ndarray, gap: tuple[int, int]) -> np.ndarray:
    """Points missing somewhere in ``gap`` (the limb) among the window's query poses at frames ``grid [F]`` with
    weights ``w [F, P]`` (0 where missing)."""
    inside = (grid >= gap[0]) & (grid < gap[1])
    return np.flatnonzero((w[inside] == 0).any(axis=0)) if inside.any() else np.array([], dtype=int)


def limb_motion(feats: np.ndarray, grid: np.ndarray, w: np.ndarray, gap: tuple[int, int]) -> float:
    """How much the limb (``limb_points``) moves in the window's margins: RMS distance (cm) of its points
    ``feats [T, P, 3]`` from their own mean over the grid frames where they are observed. NaN when never."""
    limb = limb_points(w, grid, gap)
    seen = w[:, limb] > 0  # [F, L]
    if not seen.any(axis=0).all() or not len(limb):
        return float("nan")
    pts = feats[grid][:, limb]  # [F, L, 3]
    mean = (pts * seen[..., None]).sum(0) / seen.sum(0)[:, None]
    return float(np.sqrt((((pts - mean) ** 2).sum(-1) * seen).sum() / seen.sum()))


def pca_margin_error(
    pos: np.ndarray, visible: np.ndarray, grid: np.ndarray, w: np.ndarray, gap: tuple[int, int]
) -> float:
    """How well the clip's own PCA rebuilds the limb (``limb_points``) where it is observed around ``gap``: the
    limb is hidden over the window's grid frames ``grid [F]`` (gap and margins; weights ``w [F, P]``, 0 where
    missing), ``pca_fill`` rebuilds it from the rest of the clip (joint and End Site positions ``pos [T, P, 3]``,
    cm, ``visible [T, P]``), and the result is the RMS distance (cm) from the observed positions on the
    margins' grid frames: PCA's cross-validated error, to set against the neighbours' ``limb_rms``. NaN when
    the limb is never observed there or PCA cannot rebuild it."""
    limb = limb_points(w, grid, gap)
    margins = grid[(grid < gap[0]) | (grid >= gap[1])]
    seen = visible[margins][:, limb]
    if not seen.any():
        return float("nan")
    hidden = visible.copy()
    hidden[grid[0] : grid[-1] + 1, limb] = False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        filled = pca_fill(np.where(hidden[..., None], pos, np.nan), hidden)
    err = np.linalg.norm(filled[margins][:, limb] - pos[margins][:, limb], axis=-1)[seen]
    return float(np.sqrt(np.mean(err**2)))  # NaN where PCA could not rebuild a point


def fill_angles(
    motion: Motion,
    mask: np.ndarray,
    db: SkeletonDatabase,
    settings: WindowSettings | None = None,
    exclude: Iterable[str] = (),
    searcher: Searcher | None = None,
) -> tuple[np.ndarray, FillStats]:
    """Fill the masked channels of ``motion.channels [T, C]`` (degrees; ``mask [T, C]`` True = missing)
    from ``db`` (module docstring). Returns channels ``[T, C]`` (observed samples unchanged, bit for bit) and
    stats. Angles are taken as continuous along time (``fill.unwrap_observed``).

    Raises ValueError naming the motion when its skeleton does not match the database's."""
    t_start = time.process_time()
    settings = settings or WindowSettings(**ANGLE_DEFAULTS)  # validated by WindowSettings.__post_init__
    sk = motion.skeleton
    db.check(sk, motion.name)
    searcher = searcher or Searcher(db.points, db.clip, db.describe())
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
    skip = set(exclude) | {motion.name, motion.name.split("#")[0]}  # "clip#test": a time split of "clip"
    allowed = np.array([n not in skip for n in db.names])[db.clip]
    seconds = edge_seconds(mask, motion.fps)
    n_t = motion.n_frames
    complete = ~smask.any(axis=1)
    own = Searcher(feats, np.zeros(n_t, dtype=int), f"{motion.name} itself") if settings.own else None
    pos = joint_positions(motion.with_channels(base), end_sites=True) if settings.pca_gate is not None else None
    est, beta = base.copy(), np.zeros(mask.shape)  # kNN estimate and its blend weight, per sample
    twist = base.copy()  # where the PCA fallback's IK takes its twist from
    filled = np.zeros(mask.shape, dtype=bool)  # the scored missing samples the blend writes
    for a, b in runs(smask.any(axis=1)):
        unknown = np.flatnonzero(smask[a:b].any(axis=0))  # indices into scored_cols
        gain = 1.0 + settings.near_gain / np.maximum(hop_distances(sk, np.flatnonzero(joint_missing[a:b].any(0))), 1)
        nb = search_gap(searcher, own, feats, visible, gain, (a, b), motion.fps, settings, allowed, complete, stats)
        cols = scored_cols[unknown]
        traj = gather(db.channels[:, unknown], motion.channels[:, cols], nb.starts, nb.from_own, nb.span - nb.w0)
        limb = limb_rms(db.points, feats, nb.starts, nb.from_own, nb.grid, nb.w0, nb.weights, nb.kernel, (a, b))
        stats.limb_distance.append(limb)
        rms = limb if settings.limb_distance and np.isfinite(limb) else nb.rms
        gated = np.isfinite(limb) and (
            (settings.limb_gate is not None and limb > settings.limb_gate)
            or (
                settings.still_gate is not None
                and limb > settings.still_gate * limb_motion(feats, nb.grid, nb.weights, (a, b))
            )
            or (
                pos is not None
                and limb > settings.pca_gate * pca_margin_error(pos, visible, nb.grid, nb.weights, (a, b))
            )
        )
        lo = nb.span[0]
        for u, c in enumerate(cols):
            near = base[nb.span, c][:, None] + wrap_deg(traj[:, :, u] - base[nb.span, c][:, None])  # [S, k] degrees
            for c0, c1 in runs(mask[lo : nb.span[-1] + 1, c]):
                t, e, bt = estimate_run(
                    base[:, c], near, nb.kernel, seconds[:, c], lo, (c0 + lo, c1 + lo), rms, settings
                )
                est[t, c], beta[t, c], filled[t, c] = e, 0.0 if gated else bt, True
                if settings.twist != "lerp" and (settings.gated_twist or not gated):
                    twist[t, c] = e if settings.twist == "knn" else base[t, c] + bt * (e - base[t, c])
    if settings.fallback == "pca":
        keep = None if settings.short_chain is None else short_chains(sk, settings.short_chain)
        hidden = own_hidden(sk, joint_missing) if settings.pca_pair else None
        anchor = pca_angles(motion, mask, twist, visible, keep, settings.fit_twist, hidden)
    else:
        anchor = base
    a, b, e = anchor[filled], beta[filled], est[filled]
    out[filled] = np.where(b == 1.0, e, a + b * (e - a))  # β = 1 (``speed`` None): the estimate exactly
    out[~mask] = motion.channels[~mask]
    stats.total_s = time.process_time() - t_start
    return out, stats


def angle_filler(
    db: SkeletonDatabase, settings: WindowSettings, exclude: Iterable[str] = ()
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """``clean(noisy, mask) -> [T, C]`` for the harness, with one searcher shared by every call."""
    searcher = Searcher(db.points, db.clip, db.describe())
    skip = tuple(exclude)

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return fill_angles(noisy, mask, db, settings, skip, searcher)[0]

    clean.database = db.describe()  # type: ignore[attr-defined]
    return clean


@register(
    "knn",
    "angles",
    help="kNN in joint space from a large clean database (default: the largest corpus of the skeleton, cached), "
    "offset-corrected and blended with the clip's PCA fill; options k, margin_s, near_gain, speed, offset, "
    "query_hz, distance_gain, own, fallback, max_weight, limb_distance, plateau_s, twist, limb_gate, still_gate, "
    "gated_twist, short_chain, pca_gate, fit_twist, pca_pair, database",
)
def _knn_angles(
    context: MethodContext, database: str | None = None, **options: Any
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """``knn`` for BVH data. The database is ``database`` (corpus name or folder of BVH files) or else the
    largest corpus of the input's skeleton under the data root, or else ``context.train``. When the
    database is the corpus being scored, only its training clips (``context.train``) are used; the clip
    being filled (same name, or the clip it was cut from: ``clip#test`` leaves out ``clip``) is always
    left out, and a one-clip corpus that is only the input itself gives way to ``context.train``. The
    database is built on the first call."""
    settings = WindowSettings(**{**ANGLE_DEFAULTS, **options})  # an unknown option: TypeError, see build_method
    built: dict[tuple, Callable[[Motion, np.ndarray], np.ndarray]] = {}

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        key = noisy.skeleton.topology()
        if key not in built:
            corpus = database or default_corpus(noisy.skeleton)
            db = cached_database(corpus) if corpus is not None else None
            if db is not None and set(db.names) <= {noisy.name, noisy.name.split("#")[0]}:
                db = None  # a one-clip corpus (cmu120) whose clip is the input: nothing else to learn from
            if db is None and context.train:
                db = SkeletonDatabase.from_motions(list(context.train), source=context.corpus or "training clips")
            if db is None:
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
