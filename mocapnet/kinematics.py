"""Forward kinematics, bone-length-preserving inverse kinematics and rotation helpers (scipy Rotation).

BVH convention: a joint's rotation channels, in file order, compose as intrinsic rotations
(``Zrotation Xrotation Yrotation`` → ``R = Rz @ Rx @ Ry``); a joint with position channels uses them as its
local translation in place of its offset.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.motion import Markers, Motion, Skeleton

#: A NumPy array or a torch tensor: ``%`` is the floor modulo of both (``np.remainder``, ``torch.remainder``),
#: so the wrap formulas below serve the networks too without this module importing torch.
Angles = TypeVar("Angles")


def wrap_deg(deg: Angles) -> Angles:
    """Angles (degrees, any shape) wrapped to ``[-180, 180)``."""
    return (deg + 180.0) % 360.0 - 180.0


def wrap_near(values: Angles, center: Angles) -> Angles:
    """``values`` (degrees) moved by multiples of 360 into ``(center - 180, center + 180]`` (broadcast)."""
    return center - wrap_deg(center - values)


def rotation_sequence(skeleton: Skeleton, joint: int) -> tuple[str, np.ndarray]:
    """Intrinsic axis sequence (e.g. ``"ZXY"``) and the channel columns of ``joint``'s rotation channels."""
    cols = skeleton.joint_channels(joint)
    rot = [(c, name[0]) for c, name in zip(cols, skeleton.channels[joint]) if name.endswith("rotation")]
    return "".join(a for _, a in rot), np.array([c for c, _ in rot], dtype=int)


def _axis_matrices(axis: str, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` about ``axis`` from the angles' cosines and sines ``[...]``."""
    i = "XYZ".index(axis.upper())
    j, k = (i + 1) % 3, (i + 2) % 3
    out = np.zeros(cos.shape + (3, 3))
    out[..., i, i] = 1.0
    out[..., j, j] = cos
    out[..., k, k] = cos
    out[..., j, k] = -sin
    out[..., k, j] = sin
    return out


def euler_to_matrix(angles_deg: np.ndarray, seq: str) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` of intrinsic Euler angles ``[..., len(seq)]`` (degrees, upper-case
    ``seq`` as in a BVH file: ``"ZXY"`` → ``Rz @ Rx @ Ry``); equals scipy's ``Rotation.from_euler(seq, …,
    degrees=True).as_matrix()`` to rounding, for any leading shape at once (and ~4× faster on many)."""
    rad = np.radians(angles_deg)
    cos, sin = np.cos(rad), np.sin(rad)
    out = _axis_matrices(seq[0], cos[..., 0], sin[..., 0])
    for n, axis in enumerate(seq[1:], start=1):
        # out @ R_axis changes only the two columns j, k of the rotation plane (4 products, no matmul).
        i = "XYZ".index(axis.upper())
        j, k = (i + 1) % 3, (i + 2) % 3
        c, s = cos[..., n, None], sin[..., n, None]
        col_j, col_k = out[..., :, j].copy(), out[..., :, k]
        out[..., :, j] = col_j * c + col_k * s
        out[..., :, k] = col_k * c - col_j * s
    return out


def local_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local rotation matrices ``[T, J, 3, 3]`` from channels ``[T, C]`` (degrees); joints without rotation
    channels get the identity. All joints sharing an axis order are converted at once."""
    n_frames = channels.shape[0]
    out = np.broadcast_to(np.eye(3), (n_frames, skeleton.n_joints, 3, 3)).copy()
    for seq, joints, cols in skeleton.rotation_groups:
        out[:, joints] = euler_to_matrix(channels[:, cols], seq)
    return out


def local_translations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local translations ``[T, J, 3]`` (skeleton units): position channels where present, else offsets."""
    n_frames = channels.shape[0]
    out = np.broadcast_to(skeleton.offsets, (n_frames, skeleton.n_joints, 3)).copy()
    joints, axes, cols = skeleton.position_channels
    out[:, joints, axes] = channels[:, cols]
    return out


def global_transforms(
    skeleton: Skeleton, channels: np.ndarray, rot_l: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``[T, J, 3, 3]`` and positions ``[T, J, 3]`` (skeleton units); ``rot_l`` may pass
    ``local_rotations(skeleton, channels)`` when it is already known."""
    rot_l = local_rotations(skeleton, channels) if rot_l is None else rot_l
    trans_l = local_translations(skeleton, channels)
    rot_g = np.empty_like(rot_l)
    pos_g = np.empty_like(trans_l)
    for j, p in enumerate(skeleton.parents):
        if p < 0:
            rot_g[:, j] = rot_l[:, j]
            pos_g[:, j] = trans_l[:, j]
        else:
            rot_g[:, j] = rot_g[:, p] @ rot_l[:, j]
            pos_g[:, j] = pos_g[:, p] + np.einsum("tab,tb->ta", rot_g[:, p], trans_l[:, j])
    return rot_g, pos_g


def end_site_positions(skeleton: Skeleton, rot_g: np.ndarray, pos_g: np.ndarray) -> np.ndarray:
    """End Site positions ``[T, E, 3]`` (skeleton units) from global transforms."""
    if not skeleton.end_parents:
        return np.zeros((pos_g.shape[0], 0, 3))
    par = np.array(skeleton.end_parents)
    return pos_g[:, par] + np.einsum("teab,eb->tea", rot_g[:, par], skeleton.end_sites)


def joint_positions(motion: Motion, channels: np.ndarray | None = None, end_sites: bool = False) -> np.ndarray:
    """Forward kinematics: joint positions ``[T, J, 3]`` in cm (``[T, J + E, 3]`` with End Sites)."""
    ch = motion.channels if channels is None else channels
    rot_g, pos_g = global_transforms(motion.skeleton, ch)
    if end_sites:
        pos_g = np.concatenate([pos_g, end_site_positions(motion.skeleton, rot_g, pos_g)], axis=1)
    return pos_g * motion.skeleton.cm_per_unit


def point_labels(skeleton: Skeleton, end_sites: bool = True) -> list[str]:
    """Labels of the points of ``joint_positions``: joint names, then ``<parent>_end<e>`` per End Site."""
    ends = [f"{skeleton.names[p]}_end{e}" for e, p in enumerate(skeleton.end_parents)] if end_sites else []
    return list(skeleton.names) + ends


def motion_points(
    motion: Motion,
    channels: np.ndarray | None = None,
    end_sites: bool = True,
    visible: np.ndarray | None = None,
) -> Markers:
    """The motion as ``Markers``: joint (and End Site) positions ``[T, P, 3]`` in cm by forward kinematics
    of ``channels`` (default the motion's), labelled by ``point_labels``; ``visible [T, P]`` default all.
    The one motion → points conversion (point methods on BVH data, kNN databases, spatial noise)."""
    pos = joint_positions(motion, channels, end_sites=end_sites)
    seen = np.ones(pos.shape[:2], dtype=bool) if visible is None else visible
    return Markers(pos, seen, point_labels(motion.skeleton, end_sites), motion.fps, motion.name)


def rest_positions(skeleton: Skeleton) -> np.ndarray:
    """Joint and End Site positions ``[J + E, 3]`` of the rest pose (offsets only), skeleton units."""
    pos = np.zeros((skeleton.n_joints, 3))
    for j, p in enumerate(skeleton.parents):
        pos[j] = skeleton.offsets[j] + (pos[p] if p >= 0 else 0.0)
    ends = pos[list(skeleton.end_parents)] + skeleton.end_sites if skeleton.end_parents else np.zeros((0, 3))
    return np.concatenate([pos, ends])


def other_euler_solution(angles_deg: np.ndarray, seq: str) -> np.ndarray:
    """The other 3-axis Euler solution ``[..., 3]`` (degrees) of the same rotations as ``angles_deg [..., 3]``:
    ``(a + 180, 180 - b, c + 180)`` for Tait-Bryan ``seq`` (three different axes), ``(a + 180, -b, c + 180)``
    for proper Euler (first axis = last)."""
    alt = angles_deg + np.array([180.0, 0.0, 180.0])
    alt[..., 1] = (180.0 - angles_deg[..., 1]) if seq[0] != seq[2] else -angles_deg[..., 1]
    return alt


def matrix_to_euler(matrices: np.ndarray, seq: str, reference: np.ndarray | None = None) -> np.ndarray:
    """Euler angles ``[T, len(seq)]`` (degrees, intrinsic ``seq``) of rotation matrices ``[T, 3, 3]``.

    With ``reference`` (same shape as the result) each frame takes, of the two equivalent 3-axis
    solutions, the one nearest the reference, and every angle is wrapped to within 180° of it.
    """
    ang = Rotation.from_matrix(matrices).as_euler(seq, degrees=True)
    if reference is None:
        return ang
    ref = np.asarray(reference, dtype=np.float64)

    def near(a: np.ndarray) -> np.ndarray:
        # ``ref + wrap_deg(a - ref)`` up to rounding (adding before subtracting 180 rounds twice); kept as it
        # is so that IK, and every spatial-noise figure, stays bit for bit what it was.
        return ref + (a - ref + 180.0) % 360.0 - 180.0

    best = near(ang)
    if len(seq) == 3:
        alt = near(other_euler_solution(ang, seq))
        use_alt = np.abs(alt - ref).sum(axis=1) < np.abs(best - ref).sum(axis=1)
        best[use_alt] = alt[use_alt]
    return best


def _align(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotations ``[T, 3, 3]`` that best map direction sets ``src [T, K, 3]`` onto ``dst [T, K, 3]``.

    K = 1: the smallest rotation between the two directions; K ≥ 2: Kabsch (SVD).
    """
    if src.shape[1] == 1:
        a = src[:, 0] / np.linalg.norm(src[:, 0], axis=-1, keepdims=True)
        b = dst[:, 0] / np.linalg.norm(dst[:, 0], axis=-1, keepdims=True)
        axis = np.cross(a, b)
        sin = np.linalg.norm(axis, axis=-1)
        cos = np.clip((a * b).sum(-1), -1.0, 1.0)
        rotvec = axis / np.maximum(sin, 1e-12)[:, None] * np.arctan2(sin, cos)[:, None]
        return Rotation.from_rotvec(rotvec).as_matrix()
    h = np.einsum("tki,tkj->tij", src, dst)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("tij,tjk->tik", vt.transpose(0, 2, 1), u.transpose(0, 2, 1))))
    fix = np.broadcast_to(np.eye(3), h.shape).copy()
    fix[:, 2, 2] = d
    return vt.transpose(0, 2, 1) @ fix @ u.transpose(0, 2, 1)


def inverse_kinematics(motion: Motion, target: np.ndarray) -> np.ndarray:
    """Channels ``[T, C]`` whose forward kinematics points each bone at ``target`` while keeping every bone
    length exactly (lengths come from the skeleton's offsets).

    ``target`` holds joint and End Site positions ``[T, J + E, 3]`` in cm, as from
    ``joint_positions(motion, end_sites=True)``. For each joint with children, the rotation that maps the
    current (clean) bone directions onto the target directions is applied on top of the clean global
    rotation (a single child leaves the twist as it was; several children are fitted by Kabsch). Context
    joints and translation channels keep their values. Angles are taken nearest to ``motion.channels``.
    """
    sk = motion.skeleton
    rot_g, pos_g = global_transforms(sk, motion.channels)
    target = target / sk.cm_per_unit
    n_j = sk.n_joints
    trans_l = local_translations(sk, motion.channels)
    # Child points of each joint: (index into target, local offset)
    kids: list[list[tuple[int, np.ndarray]]] = [[] for _ in range(n_j)]
    for c in range(n_j):
        if sk.parents[c] >= 0:
            kids[sk.parents[c]].append((c, None))
    for e, p in enumerate(sk.end_parents):
        kids[p].append((n_j + e, sk.end_sites[e]))
    context = set(sk.context_joints)
    new_rot_g = rot_g.copy()
    new_pos = pos_g.copy()
    out = motion.channels.copy()
    for j in range(n_j):
        p = sk.parents[j]
        if p >= 0:
            new_pos[:, j] = new_pos[:, p] + np.einsum("tab,tb->ta", new_rot_g[:, p], trans_l[:, j])
        usable = [(k, off) for k, off in kids[j] if np.linalg.norm(trans_l[0, k] if off is None else off) > 1e-9]
        if j in context or not usable:
            # Keep the local rotation; the global one follows the (possibly changed) parent.
            if p >= 0:
                new_rot_g[:, j] = new_rot_g[:, p] @ np.swapaxes(rot_g[:, p], 1, 2) @ rot_g[:, j]
            continue
        local_off = np.stack(
            [trans_l[:, k] if off is None else np.broadcast_to(off, (len(out), 3)) for k, off in usable], axis=1
        )
        cur_dir = np.einsum("tab,tkb->tka", rot_g[:, j], local_off)
        tgt_dir = target[:, [k for k, _ in usable]] - new_pos[:, [j]]
        new_rot_g[:, j] = _align(cur_dir, tgt_dir) @ rot_g[:, j]
        local = new_rot_g[:, j] if p < 0 else np.swapaxes(new_rot_g[:, p], 1, 2) @ new_rot_g[:, j]
        seq, cols = rotation_sequence(sk, j)
        if seq:
            out[:, cols] = matrix_to_euler(local, seq, reference=motion.channels[:, cols])
    return out


def geodesic_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of ``rot_a^T rot_b`` for rotation matrices ``[..., 3, 3]``.

    ``atan2(sin, cos)`` of the relative rotation (sin from its skew part, cos from its trace): accurate to
    rounding at every angle, where ``arccos`` of the trace loses half the digits near 0° (1e-6° off).
    """
    # rel = rot_a^T rot_b: trace(rel) = Σ a∘b; its skew part is minus Σ_k (row k of a) × (row k of b)
    cos = ((rot_a * rot_b).sum(axis=(-2, -1)) - 1.0) / 2.0
    a0, a1, a2 = rot_a[..., 0], rot_a[..., 1], rot_a[..., 2]
    b0, b1, b2 = rot_b[..., 0], rot_b[..., 1], rot_b[..., 2]
    s0, s1, s2 = (a1 * b2 - a2 * b1).sum(-1), (a2 * b0 - a0 * b2).sum(-1), (a0 * b1 - a1 * b0).sum(-1)
    return np.degrees(np.arctan2(np.sqrt(s0 * s0 + s1 * s1 + s2 * s2) / 2.0, cos))
