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


def rot_err_deg(motion: Motion, cleaned: np.ndarray, truth_rot: np.ndarray | None = None) -> float:
    """Mean geodesic angle (degrees) between cleaned and true local rotations of the scored joints.

    ``truth_rot`` may pass precomputed ``local_rotations(skeleton, motion.channels)``.
    """
    sk = motion.skeleton
    if not np.isfinite(cleaned).all():
        return float("nan")
    joints = sk.scored_joints
    truth = local_rotations(sk, motion.channels) if truth_rot is None else truth_rot
    ours = local_rotations(sk, cleaned)
    return float(geodesic_deg(ours[:, joints], truth[:, joints]).mean())


def pos_err_cm(motion: Motion, cleaned: np.ndarray, truth_pos: np.ndarray | None = None) -> float:
    """Mean Euclidean distance (cm) of non-context joint positions, forward kinematics with the true root
    (context channels taken from the truth). ``truth_pos`` may pass precomputed positions ``[T, J, 3]``
    in skeleton units."""
    sk = motion.skeleton
    if not np.isfinite(cleaned[:, sk.scored_mask]).all():
        return float("nan")
    ch = cleaned.copy()
    ch[:, ~sk.scored_mask] = motion.channels[:, ~sk.scored_mask]
    _, ours = global_transforms(sk, ch)
    truth = global_transforms(sk, motion.channels)[1] if truth_pos is None else truth_pos
    joints = [j for j in range(sk.n_joints) if j not in sk.context_joints]
    return float(np.linalg.norm(ours[:, joints] - truth[:, joints], axis=-1).mean() * sk.cm_per_unit)


def point_err_cm(filled: np.ndarray, truth: np.ndarray, missing: np.ndarray) -> float:
    """Mean distance (cm) of filled points ``[T, M, 3]`` to the truth over missing samples ``[T, M]``."""
    if not missing.any():
        return float("nan")
    return float(np.linalg.norm(filled[missing] - truth[missing], axis=-1).mean())
