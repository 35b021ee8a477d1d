"""Metrics of PROTOCOL.md. Angle metrics take channels ``[T, C]`` in degrees and a scored-channel mask."""

from __future__ import annotations

import numpy as np

from mocapnet.kinematics import geodesic_deg, global_transforms, local_rotations
from mocapnet.motion import Motion


def wrapped_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b`` wrapped to [-180, 180) degrees."""
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


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


def pose_errors(
    motion: Motion, cleaned: np.ndarray, truth_rot: np.ndarray | None = None, truth_pos: np.ndarray | None = None
) -> tuple[float, float]:
    """``(rot_err_deg, pos_err_cm)`` of ``cleaned [T, C]`` against ``motion``, converting ``cleaned`` to
    rotations once for both (see ``rot_err_deg`` and ``pos_err_cm``). ``truth_rot [T, J, 3, 3]`` and
    ``truth_pos [T, J, 3]`` may pass the truth's precomputed local rotations and global positions."""
    sk = motion.skeleton
    if not np.isfinite(cleaned[:, sk.scored_mask]).all():
        return float("nan"), float("nan")
    # Context and translation channels from the truth: the scored joints' rotations stay those of `cleaned`.
    ch = cleaned.copy()
    ch[:, ~sk.scored_mask] = motion.channels[:, ~sk.scored_mask]
    rot_l = local_rotations(sk, ch)
    rot = float("nan")
    if np.isfinite(cleaned).all():
        truth = local_rotations(sk, motion.channels) if truth_rot is None else truth_rot
        joints = sk.scored_joints
        rot = float(geodesic_deg(rot_l[:, joints], truth[:, joints]).mean())
    _, ours = global_transforms(sk, ch, rot_l)
    truth_p = global_transforms(sk, motion.channels)[1] if truth_pos is None else truth_pos
    joints = [j for j in range(sk.n_joints) if j not in sk.context_joints]
    pos = float(np.linalg.norm(ours[:, joints] - truth_p[:, joints], axis=-1).mean() * sk.cm_per_unit)
    return rot, pos


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
