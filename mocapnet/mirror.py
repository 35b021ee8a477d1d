"""Left/right mirroring of joint-angle motion, for training augmentation.

A mirrored motion is what the performer's mirror image would have recorded: every joint's world position is
reflected through a vertical plane and left and right joints trade places. In a BVH whose rest pose has every
joint frame aligned with the world (CMU), that is the familiar rule (negate the lateral position and the two
rotation channels about the other axes). Many rigs are not like that: Bandai-Namco's joint frames differ from
joint to joint (its left arm bones point along +X and the right along −X, the legs' lateral axis is Y, the
shoulders' Z), so each joint ``j`` needs its own reflection ``A_j`` of its frame.

With ``M`` the world reflection and ``p(j)`` the parent, the mirrored global rotation of the partner ``j'`` is
``G'_j' = M G_j A_j``, so its local rotation is ``R'_j' = A_p(j)^T R_j A_j`` (with ``A_p = M`` above the root)
and its translation ``t'_j' = A_p(j)^T t_j``. Every ``A`` is a reflection (det −1), so ``R'`` is a rotation and
``M`` maps every joint position exactly onto its partner's mirrored position: the test that counts.

``A_j`` is chosen per joint among the 24 axis reflections (signed permutations with det −1), top-down:
1. the translations it must carry: ``A_j^T`` maps each child ``c``'s rest offset (or mean position channels)
   onto the partner child's;
2. the rotations: the mean of the mirrored local rotations ``A_p^T R_j A_j`` over the given clips should be the
   mean of the partner's own ``R_j'`` (a rig's joint frames are conventions, the data shows them).
Axis reflections differ from one another by turns of 90° or 180°, so a best choice within 45° of the partner's
mean is unambiguous even where the clips use the two sides differently (one performer's dominant hand, the
CMU sample's fingers: 31°). A skeleton whose best choice leaves a mismatch above ``max_mismatch_deg`` (45°,
the mean rotations) or a bone more than 15° from its partner's mirrored direction, or whose names do not pair
up, is refused (ValueError): mirroring it would invent poses. Bone lengths may differ left to right (a
calibrated skeleton): the mirrored motion then has the partner's bones, so its positions are the mirror image
up to that difference.

The world reflection ``M`` negates the horizontal axis listed first (X unless X is up); up is the axis along
which the body (the joints from the hips down, not a reference root left at the origin) extends furthest on
average over the clips' frames.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.kinematics import (
    global_transforms,
    local_rotations,
    local_translations,
    other_euler_solution,
    rotation_sequence,
    wrap_near,
)
from mocapnet.motion import Motion, Skeleton

_SIDE_SWAPS: tuple[tuple[str, str], ...] = (("Left", "Right"), ("left", "right"), ("LEFT", "RIGHT"))
# single-letter side tokens: suffix "_L", prefix "L_", infix "_L_" or 3ds Max's "Bip01 L Thigh", CMU's "lhumerus",
# "LHip"; a midline name may give a candidate too ("root" -> "loot"), which pairs only if that joint exists
_LETTER_PATTERNS = (
    r"(?<=[_.\- ])([LlRr])$",
    r"^([LlRr])(?=[_.\- ])",
    r"(?<=[_.\- ])([LlRr])(?=[_.\- ])",
    r"^([lr])(?=[a-z])",
    r"^([LR])(?=[A-Z][a-z])",
)
_FLIP = str.maketrans("LlRr", "RrLl")

MAX_MISMATCH_DEG = 45.0
MAX_BONE_ANGLE_DEG = 15.0


def _swapped_names(name: str) -> list[str]:
    out = []
    for a, b in _SIDE_SWAPS:
        for x, y in ((a, b), (b, a)):
            if x in name:
                out.append(name.replace(x, y))
    for pattern in _LETTER_PATTERNS:
        out.append(re.sub(pattern, lambda m: m.group(1).translate(_FLIP), name))
    return [n for n in out if n != name]


def mirror_partners(skeleton: Skeleton) -> np.ndarray:
    """``[J]`` index of each joint's left/right partner (itself on the midline), paired by name (``Left``/
    ``Right``, ``_L``/``_R``, ``L_``/``R_``, CMU's ``l``/``r`` prefix, ``.L``/``.R``). ValueError when a
    side joint has no partner or the pairing does not respect the hierarchy."""
    index = {n: j for j, n in enumerate(skeleton.names)}
    partner = np.arange(skeleton.n_joints)
    for j, name in enumerate(skeleton.names):
        found = [index[n] for n in _swapped_names(name) if n in index]
        if found:
            partner[j] = found[0]
        elif any(word in name for pair in _SIDE_SWAPS for word in pair):
            raise ValueError(f"mirror: {name!r} is a side joint with no partner on the other side")
    for j in range(skeleton.n_joints):
        if partner[partner[j]] != j:
            raise ValueError(f"mirror: joints {skeleton.names[j]!r} and {skeleton.names[partner[j]]!r} do not pair")
        p, q = skeleton.parents[j], skeleton.parents[partner[j]]
        if (p < 0) != (q < 0) or (p >= 0 and partner[p] != q):
            raise ValueError(
                f"mirror: {skeleton.names[j]!r} pairs with {skeleton.names[partner[j]]!r} but their parents do not"
            )
        if sorted(skeleton.channels[j]) != sorted(skeleton.channels[partner[j]]):
            raise ValueError(f"mirror: {skeleton.names[j]!r} and its partner have different channels")
    if (partner == np.arange(skeleton.n_joints)).all():
        raise ValueError(f"mirror: no left/right joint pairs in {skeleton.describe()}")
    return partner


def _axis_reflections() -> np.ndarray:
    """The 24 signed permutation matrices with determinant −1, ``[24, 3, 3]``, diagonal ones first."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) < 0:
                out.append(m)
    out.sort(key=lambda m: (not np.allclose(m, np.diag(np.diag(m))), -np.trace(np.abs(m))))
    return np.array(out)


def _mean_rotation(rotations: np.ndarray) -> np.ndarray:
    """Chordal mean ``[3, 3]`` of rotations ``[N, 3, 3]``."""
    u, _, vt = np.linalg.svd(rotations.mean(axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _angles_deg(rotations: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Angle (degrees) of each rotation ``[N, 3, 3]`` from ``target [3, 3]``."""
    cos = ((rotations * target).sum(axis=(-2, -1)) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@dataclass(frozen=True)
class MirrorMap:
    """How to mirror motions of one skeleton (module docstring): ``partner [J]``, ``world`` reflection
    ``M [3, 3]``, per-joint frame reflections ``frames [J, 3, 3]``; ``mismatch_deg [J]`` the fit of each joint's
    mean mirrored rotation to its partner's (0 for joints without rotation channels); ``typical_deg [C]`` the
    circular mean of every channel over the fitted clips (where a re-expressed joint's Euler angles start)."""

    skeleton: Skeleton
    partner: np.ndarray
    world: np.ndarray
    frames: np.ndarray
    mismatch_deg: np.ndarray
    typical_deg: np.ndarray

    def parent_frame(self, joint: int) -> np.ndarray:
        p = self.skeleton.parents[joint]
        return self.world if p < 0 else self.frames[p]


def _offset_error(reflection: np.ndarray, offset: np.ndarray, partner_offset: np.ndarray) -> float:
    """Angle (degrees) between ``reflection @ offset`` and ``partner_offset``; 0 when either is a zero offset
    (bone lengths may differ left to right, as in a calibrated skeleton: the directions must agree)."""
    a, b = reflection.T @ offset, partner_offset
    norm = np.linalg.norm(a) * np.linalg.norm(b)
    if norm <= 1e-12:
        return 0.0
    return float(np.degrees(np.arccos(np.clip(a @ b / norm, -1.0, 1.0))))


def _up_axis(positions: np.ndarray) -> int:
    """World axis along which the body extends furthest, averaged over frames (``positions [T, J, 3]``)."""
    extent = (positions.max(axis=1) - positions.min(axis=1)).mean(axis=0)
    return int(np.argmax(extent))


def fit_mirror(motions: Sequence[Motion], max_mismatch_deg: float = MAX_MISMATCH_DEG, stride: int = 4) -> MirrorMap:
    """The mirror map of the skeleton the ``motions`` share, fitted to their frames (every ``stride``-th).
    ValueError when the skeleton cannot be mirrored faithfully (module docstring)."""
    if not motions:
        raise ValueError("mirror: no motions to fit")
    skeleton = motions[0].skeleton
    if any(m.skeleton.topology() != skeleton.topology() for m in motions):
        raise ValueError("mirror: the motions do not share one skeleton")
    partner = mirror_partners(skeleton)
    channels = np.concatenate([m.channels[::stride] for m in motions])
    rot_l = local_rotations(skeleton, channels)
    rot_g, pos_g = global_transforms(skeleton, channels, rot_l)
    body = [j for j in range(skeleton.n_joints) if j not in skeleton.context_joints[:-1]]  # no reference root
    up = _up_axis(pos_g[:, body])
    world = np.eye(3)
    lateral = next(a for a in range(3) if a != up)
    world[lateral, lateral] = -1.0
    candidates = _axis_reflections()
    # constant translations (bones) must map onto the partner's; moving ones (root motion) are free
    trans = local_translations(skeleton, channels)
    fixed = trans.std(axis=0).max(axis=1) <= 1e-6 * max(float(np.abs(trans).max()), 1.0)
    trans_mean = trans.mean(axis=0)
    allowed = np.ones((skeleton.n_joints, len(candidates)), dtype=bool)
    for j in range(skeleton.n_joints):
        pairs = [(trans_mean[c], trans_mean[partner[c]]) for c in skeleton.children[j] if fixed[c]]
        offset_err = np.array([max((_offset_error(a, *pair) for pair in pairs), default=0.0) for a in candidates])
        allowed[j] = offset_err <= MAX_BONE_ANGLE_DEG
        if not allowed[j].any():
            raise ValueError(
                f"mirror: the bones below {skeleton.names[j]!r} point {offset_err.min():.0f}° away from the mirror "
                f"image of those below {skeleton.names[partner[j]]!r}: the rest skeleton is not mirror-symmetric"
            )
    # Joints that carry the heading (the root chain to the hips) have a mean rotation that depends on where the
    # performer faced: they must keep the world's up direction seen in their frame (``G_j^T up``, which the
    # mirror maps to ``A_j^T G_j^T up``); every reflection that does within ``max_mismatch_deg`` is tried, the rest
    # of the tree is then chosen joint by joint, and the assignment with the smallest total mismatch wins.
    rotates = [bool(skeleton.rotation_mask[skeleton.joint_channels(j)].any()) for j in range(skeleton.n_joints)]
    heading = [j for j in skeleton.context_joints if rotates[j]]
    options = []
    for j in heading:
        u, v = rot_g[:, j, up, :].mean(axis=0), rot_g[:, partner[j], up, :].mean(axis=0)
        cos = (np.swapaxes(candidates, -1, -2) @ u) @ v / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-12)
        err = np.where(allowed[j], np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), np.inf)
        options.append([(int(i), float(err[i])) for i in np.flatnonzero(err <= max(err.min(), max_mismatch_deg))])
    means = np.array([_mean_rotation(rot_l[:, j]) for j in range(skeleton.n_joints)])
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for choice in itertools.product(*options):
        frames = np.zeros((skeleton.n_joints, 3, 3))
        mismatch = np.zeros(skeleton.n_joints)
        forced = dict(zip(heading, choice))
        for j in range(skeleton.n_joints):  # parents come before children
            a_p = world if skeleton.parents[j] < 0 else frames[skeleton.parents[j]]
            if not rotates[j]:  # its rotation is the identity and must stay so: A_j = A_p
                pick = int(np.flatnonzero((candidates == a_p).all(axis=(1, 2)))[0])
                mismatch[j] = 0.0 if allowed[j, pick] else np.inf
            elif j in forced:
                pick, mismatch[j] = forced[j]
            else:
                errors = np.where(allowed[j], _angles_deg(a_p.T @ means[j] @ candidates, means[partner[j]]), np.inf)
                pick = int(np.argmin(errors))
                mismatch[j] = errors[pick]
            frames[j] = candidates[pick]
        total = float(mismatch.sum())
        if best is None or total < best[0]:
            best = (total, frames, mismatch)
    _, frames, mismatch = best  # type: ignore[misc]
    worst = int(np.argmax(mismatch))
    if not np.isfinite(mismatch[worst]):
        raise ValueError(
            f"mirror: {skeleton.names[worst]!r} has no rotation channels, and the bones below it are not mirror "
            "images in its parent's mirrored frame"
        )
    if mismatch[worst] > max_mismatch_deg:
        raise ValueError(
            f"mirror: {skeleton.names[worst]!r} mirrored is {mismatch[worst]:.1f}° from "
            f"{skeleton.names[partner[worst]]!r} on average (> {max_mismatch_deg:g}°): no axis reflection of its "
            "frame matches, so its joint frames are not mirror images"
        )
    rad = np.radians(channels)
    typical = np.degrees(np.arctan2(np.sin(rad).mean(axis=0), np.cos(rad).mean(axis=0)))
    return MirrorMap(skeleton, partner, world, frames, mismatch, typical)


def _continuous_euler(matrices: np.ndarray, seq: str, start: np.ndarray) -> np.ndarray:
    """Euler angles ``[T, 3]`` of ``matrices [T, 3, 3]``: the first frame on the solution (of the two) nearest
    ``start [3]``, each later one nearest the previous frame's, wrapped to within 180° of it (continuous)."""
    ang = Rotation.from_matrix(matrices).as_euler(seq, degrees=True)
    alt = other_euler_solution(ang, seq)
    out = np.empty_like(ang)
    prev = np.asarray(start, dtype=np.float64)
    for t in range(len(ang)):
        a, b = wrap_near(ang[t], prev), wrap_near(alt[t], prev)
        prev = out[t] = a if np.abs(a - prev).sum() <= np.abs(b - prev).sum() else b
    return out


def mirror_motion(motion: Motion, mirror: MirrorMap) -> Motion:
    """``motion`` mirrored left/right (module docstring); named ``<name>#mirror``. Rotation channels that only
    change sign under the mirror keep their values' branch exactly; others are continuous over time."""
    skeleton = motion.skeleton
    if skeleton.topology() != mirror.skeleton.topology():
        raise ValueError(f"{motion.name}: skeleton differs from the one the mirror map was fitted to")
    rot_l = local_rotations(skeleton, motion.channels)
    trans_l = local_translations(skeleton, motion.channels)
    out = motion.channels.copy()
    pos_joints, pos_axes, pos_cols = skeleton.position_channels
    for j in range(skeleton.n_joints):
        q = int(mirror.partner[j])
        a_p, a_j = mirror.parent_frame(j), mirror.frames[j]
        seq, cols_j = rotation_sequence(skeleton, j)
        if len(seq):
            seq_q, cols_q = rotation_sequence(skeleton, q)
            sign = _sign_flips(a_p, a_j, seq) if seq_q == seq else None
            if sign is not None:
                out[:, cols_q] = motion.channels[:, cols_j] * sign
            elif len(seq) != 3:
                raise ValueError(
                    f"{motion.name}: {skeleton.names[j]} has {len(seq)} rotation channels and its mirrored rotation is "
                    "not a sign change of them (mirroring re-expresses it with all 3)"
                )
            else:
                out[:, cols_q] = _continuous_euler(a_p.T @ rot_l[:, j] @ a_j, seq_q, mirror.typical_deg[cols_q])
        sel = pos_joints == q
        if sel.any():
            moved = trans_l[:, j] @ a_p  # rows of A_p^T t
            out[:, pos_cols[sel]] = moved[:, pos_axes[sel]]
    return replace(motion, channels=out, name=f"{motion.name}#mirror")


def _sign_flips(a_p: np.ndarray, a_j: np.ndarray, seq: str) -> np.ndarray | None:
    """When ``a_p == a_j`` is diagonal, ``A R(angles) A`` is ``R`` of the angles with signs flipped: the
    ``[3]`` signs, else None."""
    if not np.array_equal(a_p, a_j) or not np.array_equal(a_p, np.diag(np.diag(a_p))):
        return None
    d = np.diag(a_p)
    # a rotation about axis i conjugated by diag(d) turns by d_i * det(diag(d)) = -d_i
    return np.array([-d["XYZ".index(axis)] for axis in seq])
