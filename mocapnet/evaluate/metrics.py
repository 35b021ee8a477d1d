"""Metrics of PROTOCOL.md. Angle metrics take channels ``[T, C]`` in degrees and a scored-channel mask."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapnet.kinematics import geodesic_deg, global_transforms, local_rotations, wrap_deg
from mocapnet.motion import Motion


def wrapped_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` wrapped to [-180, 180) degrees."""
    return wrap_deg(np.asarray(a) - np.asarray(b))


def angle_err_deg(cleaned: np.ndarray, truth: np.ndarray, scored: np.ndarray) -> float:
    """RMS over frames and scored channels of the wrapped difference (degrees); NaN samples (left missing
    by a method) are excluded."""
    d = wrapped_diff(cleaned[:, scored], truth[:, scored])
    return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else float("nan")


def gap_err_deg(cleaned: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """RMS of the wrapped difference over missing samples only (``mask [T, C]`` True); NaN without gaps or
    when the method left them missing."""
    if not mask.any():
        return float("nan")
    d = wrapped_diff(cleaned[mask], truth[mask])
    return float(np.sqrt(np.mean(d**2))) if np.isfinite(d).all() else float("nan")


POSE_BATCH_FRAMES = 100_000  # frames converted together by pose_errors_many (bounds its memory)


def pose_errors_many(
    motion: Motion,
    outputs: Sequence[np.ndarray],
    truth_rot: np.ndarray | None = None,
    truth_pos: np.ndarray | None = None,
) -> list[tuple[float, float]]:
    """``(rot_err_deg, pos_err_cm)`` of each cleaned ``[T, C]`` in ``outputs`` against ``motion`` (see
    ``rot_err_deg`` and ``pos_err_cm``), converting each output to rotations once for both errors and many
    outputs in one batch (the cost of a short clip is per call, not per frame). ``truth_rot [T, J, 3, 3]``
    and ``truth_pos [T, J, 3]`` may pass the truth's local rotations and global positions."""
    sk = motion.skeleton
    truth = motion.channels
    if truth_rot is None:
        truth_rot = local_rotations(sk, truth)
    if truth_pos is None:
        truth_pos = global_transforms(sk, truth, truth_rot)[1]
    nan = float("nan")
    result = [(nan, nan)] * len(outputs)
    usable = [i for i, out in enumerate(outputs) if np.isfinite(out[:, sk.scored_mask]).all()]
    joints_rot = sk.scored_joints
    joints_pos = np.array([j for j in range(sk.n_joints) if j not in sk.context_joints], dtype=int)
    per_batch = max(1, POSE_BATCH_FRAMES // max(1, motion.n_frames))
    for first in range(0, len(usable), per_batch):
        batch = usable[first : first + per_batch]
        # Context and translation channels from the truth: the scored joints' rotations stay the output's.
        ch = np.stack([outputs[i] for i in batch])
        ch[:, :, ~sk.scored_mask] = truth[:, ~sk.scored_mask]
        flat = ch.reshape(-1, sk.n_channels)
        rot_l = local_rotations(sk, flat)
        _, pos = global_transforms(sk, flat, rot_l)
        shape = (len(batch), motion.n_frames)
        rot = geodesic_deg(rot_l.reshape(shape + rot_l.shape[1:])[:, :, joints_rot], truth_rot[:, joints_rot])
        pos = pos.reshape(shape + pos.shape[1:])[:, :, joints_pos] - truth_pos[:, joints_pos]
        dist = np.linalg.norm(pos, axis=-1)
        for k, i in enumerate(batch):
            rot_err = float(rot[k].mean()) if np.isfinite(outputs[i]).all() else nan
            result[i] = (rot_err, float(dist[k].mean() * sk.cm_per_unit))
    return result


def pose_errors(
    motion: Motion, cleaned: np.ndarray, truth_rot: np.ndarray | None = None, truth_pos: np.ndarray | None = None
) -> tuple[float, float]:
    """``(rot_err_deg, pos_err_cm)`` of one cleaned ``[T, C]`` (``pose_errors_many`` of one output)."""
    return pose_errors_many(motion, [cleaned], truth_rot, truth_pos)[0]


def rot_err_deg(motion: Motion, cleaned: np.ndarray, truth_rot: np.ndarray | None = None) -> float:
    """Mean geodesic angle (degrees) between cleaned and true local rotations of the scored joints; NaN when
    ``cleaned`` has a missing sample. ``truth_rot`` may pass ``local_rotations(skeleton, motion.channels)``."""
    return pose_errors(motion, cleaned, truth_rot=truth_rot)[0]


def pos_err_cm(motion: Motion, cleaned: np.ndarray, truth_pos: np.ndarray | None = None) -> float:
    """Mean Euclidean distance (cm) of non-context joint positions, forward kinematics with the true root
    (context channels taken from the truth); NaN when a scored channel is missing. ``truth_pos`` may pass
    precomputed positions ``[T, J, 3]`` in skeleton units."""
    return pose_errors(motion, cleaned, truth_pos=truth_pos)[1]


def point_err_cm(filled: np.ndarray, truth: np.ndarray, missing: np.ndarray) -> float:
    """Mean distance (cm) of filled points ``[T, M, 3]`` to the truth over missing samples ``[T, M]``."""
    if not missing.any():
        return float("nan")
    return float(np.linalg.norm(filled[missing] - truth[missing], axis=-1).mean())
