"""Denoising benchmark of C3D marker trajectories: ``gaussian-cv`` (``adaptive_smooth.cv_gaussian_runs``) against
fixed-width Gaussians on real takes with white noise added (``scripts/bench_c3d_smooth.py``).

Each take's measured samples are the reference (they hold the lab's own measurement noise, so the figures are
of the noise we add on top). White noise of ``LEVELS_MM`` standard deviation is added to every coordinate of
every measured sample (seeded per take and level); each method smooths each marker's visible runs on its own
(gaps are never bridged). Score: RMS over measured samples and coordinates of output − reference, in mm; at
level 0 that is the change a method makes to the take as recorded. Fixed widths are in milliseconds (the frames
follow each take's rate): what a user of a spline/Gaussian tool picks without knowing the noise. "best fixed"
is, per level, the single fixed width with the smallest mean over takes — an oracle no user has. "own noise"
estimates the white noise a take already holds (``own_noise_mm``): where it is large, a smoother that removes it
is scored as changing the take, so "worse than the input" at low added noise can mean "removed the lab's noise".
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d

from mocapnet.adaptive_smooth import cv_gaussian_runs
from mocapnet.evaluate.results import markdown_table
from mocapnet.fill import runs
from mocapnet.io import read_c3d

#: Complete or nearly complete takes of several labs, rates and motions (``data/c3d/INVENTORY.md``).
TAKES = (
    "cmu/02_01.c3d",
    "cmu/85_02.c3d",
    "hdm05/HDM_bd_01-02_01_120.c3d",
    "ezc3d/Qualisys.c3d",
    "ezc3d/FP_Type1.c3d",
    "btkdata/PiG_Motion-FlatFoot-Hole.c3d",
    "btkdata/Eb015pi.c3d",
    "kineticstoolkit/kinematics_tennis_serve.c3d",
    "pycgm/Movement_trial.c3d",
)
LEVELS_MM = (0.0, 0.5, 1.0, 2.0, 5.0)
FIXED_MS = (5.0, 10.0, 20.0, 40.0)


def fixed_gaussian_runs(points: np.ndarray, visible: np.ndarray, sigma_frames: float) -> np.ndarray:
    """``points [T, M, 3]`` smoothed along each visible run of each marker by a Gaussian of ``sigma_frames``
    (nearest-value edges, as ``cv_gaussian_runs``)."""
    out = points.copy()
    if sigma_frames <= 0:
        return out
    for m in range(points.shape[1]):
        for a, b in runs(visible[:, m]):
            out[a:b, m] = gaussian_filter1d(points[a:b, m], sigma_frames, axis=0, mode="nearest")
    return out


def own_noise_mm(points: np.ndarray) -> float:
    """The white noise (mm, std per coordinate) a take's ``points [T, M, 3]`` (cm) already hold, from the median
    absolute second difference over measured samples (``1.4826·MAD / √6``; fast motion can only raise it)."""
    d2 = np.diff(points, n=2, axis=0)
    d2 = d2[np.isfinite(d2)]
    return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0) * 10.0) if d2.size else 0.0


def rms_mm(points: np.ndarray, reference: np.ndarray, visible: np.ndarray) -> float:
    """RMS (mm) of ``points - reference`` (cm, ``[T, M, 3]``) over the ``visible [T, M]`` samples."""
    return float(np.sqrt(np.mean((points[visible] - reference[visible]) ** 2)) * 10.0)


def run(root: Path, takes: Sequence[str] = TAKES, levels: Sequence[float] = LEVELS_MM) -> dict:
    """Per take and level, each method's RMS error (mm): ``{"rows": [...], "summary": {...}}``."""
    rows = []
    for rel in takes:
        markers = read_c3d(root / rel)
        seen, own = markers.visible, own_noise_mm(markers.points)
        for level in levels:
            rng = np.random.default_rng([zlib.crc32(rel.encode()), int(level * 1000)])
            noisy = markers.points + rng.normal(0.0, level / 10.0, markers.points.shape)
            out = {
                "noisy": rms_mm(noisy, markers.points, seen),
                "gaussian-cv": rms_mm(cv_gaussian_runs(noisy, seen)[0], markers.points, seen),
            }
            for ms in FIXED_MS:
                smooth = fixed_gaussian_runs(noisy, seen, ms / 1000.0 * markers.fps)
                out[f"gaussian-{ms:g}ms"] = rms_mm(smooth, markers.points, seen)
            rows.append(
                {"take": rel, "fps": markers.fps, "frames": markers.n_frames, "own_noise_mm": own, "level_mm": level}
                | out
            )
    return {"rows": rows, "summary": summarize(rows)}


def summarize(rows: Sequence[dict]) -> dict:
    """Per level: each method's mean error (mm) over takes, the best fixed width (oracle), and gaussian-cv's
    ratio to it and to the noisy input (mean of per-take ratios; level 0 has no ratio)."""
    out = {}
    for level in sorted({r["level_mm"] for r in rows}):
        mine = [r for r in rows if r["level_mm"] == level]
        methods = [k for k in mine[0] if k == "noisy" or k.startswith("gaussian-")]
        mean = {k: float(np.mean([r[k] for r in mine])) for k in methods}
        fixed = [k for k in methods if k.endswith("ms")]
        best = min(fixed, key=mean.get)
        entry = {"mean_mm": mean, "best_fixed": best}
        if level > 0:
            entry["cv_over_best_fixed"] = float(np.mean([r["gaussian-cv"] / r[best] for r in mine]))
            entry["cv_over_noisy"] = float(np.mean([r["gaussian-cv"] / r["noisy"] for r in mine]))
            entry["cv_worse_than_noisy"] = [r["take"] for r in mine if r["gaussian-cv"] > r["noisy"]]
        out[f"{level:g}"] = entry
    return out


def markdown(report: dict) -> str:
    """The report as Markdown: the summary per level, then every take."""
    rows, summary = report["rows"], report["summary"]
    methods = [k for k in rows[0] if k == "noisy" or k.startswith("gaussian-")]
    lines = [
        "# C3D denoising: gaussian-cv against fixed Gaussians (white noise added to real takes)\n",
        f"Command: `{report['command']}`  ",
        f"Git commit: `{report['git_commit']}`; {report['machine']}\n",
        (__doc__ or "").split("\n\n", 1)[1].strip() + "\n",
        "## Mean RMS error over takes (mm; level 0: the change made to the take as recorded)\n",
    ]
    head = ["added noise (mm)", *methods, "best fixed", "cv ÷ best fixed", "cv ÷ noisy", "cv worse than input"]
    body = []
    for level, entry in summary.items():
        ratios = [f"{entry[k]:.3f}" if k in entry else "—" for k in ("cv_over_best_fixed", "cv_over_noisy")]
        worse = ", ".join(entry.get("cv_worse_than_noisy", [])) or ("—" if level == "0" else "none")
        body.append([level, *(f"{entry['mean_mm'][m]:.3f}" for m in methods), entry["best_fixed"], *ratios, worse])
    lines += [*markdown_table(head, body), "", "## Per take (RMS error, mm)\n"]
    head = ["take", "fps", "frames", "own noise (mm)", "added (mm)", *methods]
    body = [
        [r["take"], f"{r['fps']:g}", str(r["frames"]), f"{r['own_noise_mm']:.3f}", f"{r['level_mm']:g}"]
        + [f"{r[m]:.3f}" for m in methods]
        for r in rows
    ]
    lines += [*markdown_table(head, body), ""]
    return "\n".join(lines)
