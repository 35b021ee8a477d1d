"""The baselines users already have: Gaussian smoothing and linear / cubic-spline interpolation.

The array functions live in ``mocapnet.fill`` (re-exported here: ``gaussian_smooth``, ``lerp_fill``,
``spline_fill``); this module registers the methods built on them. Methods change only
the skeleton's scored channels; gaps (mask True) are filled before any smoothing. Angles are taken as continuous
along time (``read_bvh``; a file with gaps: ``fill.unwrap_observed``, which ``mocapnet clean`` runs).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapnet.adaptive_smooth import cv_gaussian, cv_gaussian_runs, grid_for_rate
from mocapnet.corrupt import corrupt_motion, seed_for
from mocapnet.fill import gaussian_smooth, lerp_fill, mask_groups, spline_fill
from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Markers, Motion
from mocapnet.selfcheck import limit_change

__all__ = ["gaussian_smooth", "lerp_fill", "mask_groups", "spline_fill", "tune_sigmas", "SIGMA_GRID_S"]


def _scored_only(noisy: Motion, result: np.ndarray) -> np.ndarray:
    """Keep unscored (context, translation) channels exactly as the input."""
    out = noisy.channels.copy()
    scored = noisy.skeleton.scored_mask
    out[:, scored] = result[:, scored]
    return out


@register("noisy", "angles", help="the corrupted input itself (gaps stay missing and are not scored)")
def _noisy(context: MethodContext):
    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return noisy.channels.copy()

    return clean


def _gaussian_method(sigma_s: float):
    def factory(context: MethodContext):
        def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
            return _scored_only(noisy, gaussian_smooth(lerp_fill(noisy.channels, mask), sigma_s, noisy.fps))

        return clean

    return factory


register("gaussian-58ms", "angles", help="Gaussian smoothing, sigma 58 ms (gaps filled linearly first)")(
    _gaussian_method(0.058)
)
register("gaussian-125ms", "angles", help="Gaussian smoothing, sigma 125 ms (gaps filled linearly first)")(
    _gaussian_method(0.125)
)
register("lerp+gaussian-58ms", "angles", help="linear interpolation over gaps, then Gaussian 58 ms")(
    _gaussian_method(0.058)
)


#: The self-check factor of ``gaussian-58ms+check`` (``selfcheck.limit_change``).
CHECK_LIMIT = 1.5


@register(
    "gaussian-58ms+check",
    "angles",
    help="Gaussian smoothing, sigma 58 ms (gaps filled linearly first), self-checked: a channel's RMS change is "
    f"capped at limit x the white noise it shows (selfcheck.limit_change); option limit (default {CHECK_LIMIT:g})",
)
def _gaussian_checked(context: MethodContext, limit: float = CHECK_LIMIT):
    limit = float(limit)
    if not limit > 0:
        raise ValueError(f"gaussian-58ms+check: limit must be positive, got {limit!r}")

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        base = lerp_fill(noisy.channels, mask)
        scored = noisy.skeleton.scored_mask
        base[:, scored] = limit_change(base[:, scored], gaussian_smooth(base[:, scored], 0.058, noisy.fps), limit)
        return _scored_only(noisy, base)

    return clean


@register(
    "gaussian-cv",
    "angles",
    help="Gaussian smoothing with each channel's width chosen by leave-one-out cross-validation over the observed "
    "frames, from 0.25 (the input kept) to 16 frames, at most 0.53 s (adaptive_smooth.cv_gaussian; gaps filled "
    "linearly first); no training, no noise estimate",
)
def _gaussian_cv(context: MethodContext):
    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        base = lerp_fill(noisy.channels, mask)
        scored = noisy.skeleton.scored_mask
        base[:, scored] = cv_gaussian(base[:, scored], grid_for_rate(noisy.fps), observed=~mask[:, scored])[0]
        return _scored_only(noisy, base)

    return clean


@register("lerp", "angles", help="linear interpolation over gaps (no smoothing)")
def _lerp(context: MethodContext):
    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return _scored_only(noisy, lerp_fill(noisy.channels, mask))

    return clean


@register("spline", "angles", help="cubic spline over gaps (no smoothing)")
def _spline(context: MethodContext):
    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return _scored_only(noisy, spline_fill(noisy.channels, mask))

    return clean


SIGMA_GRID_S = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.058, 0.07, 0.085, 0.1, 0.125, 0.15, 0.2, 0.25, 0.3)


def tune_sigmas(
    train: Sequence[Motion],
    corruption: str,
    corpus: str = "",
    grid_s: Sequence[float] = SIGMA_GRID_S,
    max_clips: int = 400,
    sweeps: int = 4,
) -> np.ndarray:
    """One Gaussian σ (seconds, from ``grid_s``) per channel ``[C]`` minimising the figure the harness
    reports: the mean over clips of each clip's RMS angle error over its scored channels.

    Each clip (at most ``max_clips``, evenly spaced) is corrupted once with ``corruption`` (seeded by corpus,
    clip name and repeat -1, so never the test seeds); gaps are filled linearly before smoothing. The figure
    does not split by channel, so the σ are found by coordinate descent: start from the best single σ for
    every channel, then give each channel in turn its best σ with the others fixed (``sweeps`` rounds, or
    until nothing changes). Unscored channels get ``grid_s[0]``.
    """
    if not train:
        raise ValueError("gaussian-tuned needs training clips (a corpus with training folds)")
    step = max(1, len(train) // max_clips)
    clips = list(train)[::step][:max_clips]
    scored = clips[0].skeleton.scored_mask
    # sse[k, g, c]: squared error of clip k's scored channel c smoothed with grid_s[g], summed over frames
    sse = np.zeros((len(clips), len(grid_s), int(scored.sum())))
    count = np.zeros(len(clips))
    for k, motion in enumerate(clips):
        noisy, mask = corrupt_motion(
            motion, corruption, np.random.default_rng(seed_for(corpus, motion.name, -1, corruption))
        )
        base = lerp_fill(noisy[:, scored], mask[:, scored])
        for g, sigma in enumerate(grid_s):
            err = gaussian_smooth(base, sigma, motion.fps) - motion.channels[:, scored]
            sse[k, g] = np.nansum(err**2, axis=0)
        count[k] = np.isfinite(base).sum()

    def figure(total: np.ndarray) -> np.ndarray:
        """Mean over clips of the RMS, for clip totals ``[clips, ...]`` of squared error."""
        return np.sqrt(total / count.reshape((-1,) + (1,) * (total.ndim - 1))).mean(axis=0)

    cols = np.arange(sse.shape[2])
    choice = np.full(cols.size, int(np.argmin(figure(sse.sum(axis=2)))))
    for _ in range(sweeps):
        changed = False
        for c in cols:
            others = sse[:, choice, cols].sum(axis=1) - sse[:, choice[c], c]
            best = int(np.argmin(figure(others[:, None] + sse[:, :, c])))
            if best != choice[c] and figure(others + sse[:, best, c]) < figure(others + sse[:, choice[c], c]):
                choice[c], changed = best, True
        if not changed:
            break
    sigmas = np.full(scored.size, float(grid_s[0]))
    sigmas[scored] = np.asarray(grid_s, dtype=np.float64)[choice]
    return sigmas


@register(
    "gaussian-tuned",
    "angles",
    help="Gaussian with one sigma per channel tuned on the training folds (to minimise the mean over clips of "
    "each clip's RMS error); option tune_on=CORPUS tunes on that corpus's fold-0 training folds instead",
)
def _gaussian_tuned(
    context: MethodContext, corruption: str | None = None, max_clips: int = 400, tune_on: str | None = None
):
    train, corpus = context.train, context.corpus
    if tune_on:
        from mocapnet.corpus import load_corpus

        tuning = load_corpus(tune_on, progress=False)
        train, corpus = tuning.split(0)[0], tuning.name
    sigmas = tune_sigmas(train, corruption or context.corruption, corpus, max_clips=max_clips)

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        return _scored_only(noisy, gaussian_smooth(lerp_fill(noisy.channels, mask), sigmas, noisy.fps))

    clean.sigmas_s = sigmas  # type: ignore[attr-defined]
    return clean


def _point_fill(fill):
    def factory(context: MethodContext):
        def clean(noisy: Markers) -> np.ndarray:
            t, m, _ = noisy.points.shape
            flat_mask = np.repeat(~noisy.visible, 3, axis=1)
            return fill(noisy.points.reshape(t, m * 3), flat_mask).reshape(t, m, 3)

        return clean

    return factory


register("lerp", "points", help="linear interpolation of each coordinate over gaps")(_point_fill(lerp_fill))


@register(
    "gaussian-cv",
    "points",
    help="denoising: each marker coordinate smoothed along each run of visible frames by the Gaussian whose width "
    "leave-one-out cross-validation picks (0.25 = kept, to 16 frames, at most 0.53 s; "
    "adaptive_smooth.cv_gaussian_runs); gaps stay missing; mocapnet clean writes the new positions and keeps each "
    "sample's residual and cameras",
)
def _gaussian_cv_points(context: MethodContext):
    def clean(noisy: Markers) -> np.ndarray:
        return cv_gaussian_runs(noisy.points, noisy.visible, grid_for_rate(noisy.fps))[0]

    clean.moves_measured = True  # type: ignore[attr-defined]  (a smoother: clean_c3d_file writes measured samples)
    return clean


register("spline", "points", help="cubic spline of each coordinate over gaps")(_point_fill(spline_fill))
