"""Per-frame network inputs computed with numpy (no torch): scored channels, root angular velocity, and the
normaliser statistics the models keep as buffers.

The networks see, per frame, the skeleton's scored rotation channels (degrees, as in the file, unwrapped
along time) and the 3-D angular velocity of the context chain's last joint (the hips), expressed in that
joint's own frame so it does not change when the whole motion turns about the vertical (rad/s).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.kinematics import euler_to_matrix, rotation_sequence, wrap_near
from mocapnet.motion import Motion, Skeleton

#: Floor on the per-channel normalising scale (degrees): nearly constant channels stay finite.
MIN_SCALE_DEG = 0.05


def topology_hash(skeleton: Skeleton) -> str:
    """Short stable hash (16 hex digits) of ``skeleton.topology()``: a checkpoint applies to a skeleton
    exactly when the hashes match."""
    return hashlib.sha256(repr(skeleton.topology()).encode()).hexdigest()[:16]


def scored_index(skeleton: Skeleton) -> np.ndarray:
    """Column indices ``[C_s]`` of the scored channels in the ``[T, C]`` channel array."""
    return np.flatnonzero(skeleton.scored_mask)


def scored_joint_of_channel(skeleton: Skeleton) -> np.ndarray:
    """For each scored channel, the index (0 … J_s-1) of its joint among the scored joints, ``[C_s]``.

    Gaps remove every rotation channel of a joint together; this maps a per-joint mask to channels.
    """
    joint_of_col = np.repeat(np.arange(skeleton.n_joints), np.diff(skeleton.channel_offsets))
    joints = joint_of_col[scored_index(skeleton)]
    return np.searchsorted(skeleton.scored_joints, joints)


def context_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Global rotation matrices ``[T, 3, 3]`` of the last context joint (the hips) from channels ``[T, C]``."""
    rot = np.broadcast_to(np.eye(3), (channels.shape[0], 3, 3))
    for joint in skeleton.context_joints:
        seq, cols = rotation_sequence(skeleton, joint)
        if seq:
            rot = rot @ euler_to_matrix(channels[:, cols], seq)
    return np.ascontiguousarray(rot)


def _axis_matrix(axis: str, angle_rad: float) -> np.ndarray:
    """3×3 rotation by ``angle_rad`` about ``axis`` (``"X"``, ``"Y"`` or ``"Z"``)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    if axis == "X":
        return np.array(((1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c)))
    if axis == "Y":
        return np.array(((c, 0.0, s), (0.0, 1.0, 0.0), (-s, 0.0, c)))
    return np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))


def context_chain(skeleton: Skeleton) -> list[tuple[str, np.ndarray]]:
    """``(axis sequence, channel columns)`` of each context joint's rotation, root first."""
    return [rotation_sequence(skeleton, joint) for joint in skeleton.context_joints]


def context_matrix(chain: list[tuple[str, np.ndarray]], frame: np.ndarray) -> np.ndarray:
    """``context_rotations`` for one frame ``[C]`` as a 3×3 matrix (``chain`` from ``context_chain``), without
    scipy's per-call overhead: the streaming cleaner calls it once per frame."""
    out = None
    for seq, cols in chain:
        for axis, angle in zip(seq, frame[cols].tolist()):
            m = _axis_matrix(axis, math.radians(angle))
            out = m if out is None else out @ m
    return np.eye(3) if out is None else out


def matrix_rotvec(rel: np.ndarray) -> np.ndarray:
    """Rotation vectors ``[N, 3]`` (rad) of rotation matrices ``[N, 3, 3]``; angles of 179° and more (rare
    between consecutive frames) go through scipy, the rest through the closed form."""
    angle = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    vee = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1) / 2.0
    small = angle < 1e-8
    out = vee * np.where(small, 1.0, angle / np.where(small, 1.0, np.sin(angle)))[:, None]
    big = angle > np.deg2rad(179.0)
    if big.any():
        out[big] = Rotation.from_matrix(rel[big]).as_rotvec()
    return out


def relative_rotvec(prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """Rotation vector ``[3]`` (rad) of ``prev⁻¹ cur`` for 3×3 rotation matrices: ``matrix_rotvec`` for one
    matrix, in scalar arithmetic (the streaming cleaner calls it once per frame)."""
    rel = prev.T @ cur
    (a, b, c), (d, e, f), (g, h, i) = rel.tolist()
    angle = math.acos(min(1.0, max(-1.0, (a + e + i - 1.0) / 2.0)))
    if angle > math.radians(179.0):
        return matrix_rotvec(rel[None])[0]
    factor = 0.5 if angle < 1e-8 else 0.5 * angle / math.sin(angle)
    return np.array(((h - f) * factor, (c - g) * factor, (d - b) * factor))


def root_angular_velocity(skeleton: Skeleton, channels: np.ndarray, fps: float) -> np.ndarray:
    """Angular velocity ``[T, 3]`` (rad/s) of the hips in their own frame: ``log(R_t⁻¹ R_{t+1})·fps``.

    Frame t holds the velocity from t-1 to t; frame 0 repeats frame 1's (zeros for a single frame).
    """
    n = channels.shape[0]
    out = np.zeros((n, 3))
    if n < 2:
        return out
    rot = context_rotations(skeleton, channels)
    out[1:] = matrix_rotvec(np.swapaxes(rot[:-1], 1, 2) @ rot[1:]) * fps
    out[0] = out[1]
    return out


@dataclass(frozen=True)
class Normaliser:
    """Per-channel input statistics, kept by the models as buffers.

    center : ``[C_s]`` circular mean of each scored channel over the training clips (degrees).
    scale : ``[C_s]`` standard deviation of each channel after wrapping it into ``center ± 180`` (degrees,
        at least ``MIN_SCALE_DEG``). Wrapping first makes the statistics immune to a clip being unwrapped
        onto another 360° branch (Bandai's near-gimbal-lock channels sit at ±180°).
    angvel_scale : ``[3]`` RMS of the root angular velocity (rad/s).
    """

    center: np.ndarray
    scale: np.ndarray
    angvel_scale: np.ndarray

    @classmethod
    def fit(cls, scored: Sequence[np.ndarray], angvel: Sequence[np.ndarray]) -> Normaliser:
        """Statistics from clean scored channels ``[T_i, C_s]`` and angular velocities ``[T_i, 3]``."""
        x = np.concatenate(list(scored), axis=0)
        rad = np.deg2rad(x)
        center = np.rad2deg(np.arctan2(np.sin(rad).mean(0), np.cos(rad).mean(0)))
        scale = np.maximum(wrap_near(x, center).std(0), MIN_SCALE_DEG)
        w = np.concatenate(list(angvel), axis=0)
        angvel_scale = np.maximum(np.sqrt((w**2).mean(0)), 1e-3)
        return cls(center, scale, angvel_scale)


@dataclass
class ClipArrays:
    """One clip as the networks see it: scored channels ``[T, C_s]`` and root angular velocity ``[T, 3]``
    (float32), the clip's per-channel std ``σ_c`` ``[C_s]`` (float64, degrees), the clip name and fps."""

    scored: np.ndarray
    angvel: np.ndarray
    sigma: np.ndarray
    name: str
    fps: float

    @classmethod
    def from_motion(cls, motion: Motion) -> ClipArrays:
        idx = scored_index(motion.skeleton)
        return cls(
            scored=motion.channels[:, idx].astype(np.float32),
            angvel=root_angular_velocity(motion.skeleton, motion.channels, motion.fps).astype(np.float32),
            sigma=motion.channels[:, idx].std(0),
            name=motion.name,
            fps=motion.fps,
        )
