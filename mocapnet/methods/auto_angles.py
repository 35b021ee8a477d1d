"""``auto`` for joint angles (BVH): the best cleaner shipped for the clip's skeleton, and a checked baseline
for any other skeleton, so that the default clean works on every valid file.

Per clip (``auto_plan``):

* a skeleton with a shipped EBF (``mocapnet/checkpoints/index.json``, matched by topology) trained at the
  clip's frame rate: ``ebf``; with gaps to fill, ``ebd+ebf`` when an EBD is shipped too (else ``ebf``, which
  bridges gaps linearly first);
* below ``MIN_SMOOTH_FPS`` (10 frames/s: keyframes or a subsampled take): ``lerp`` — samples kept, gaps bridged;
* any other skeleton or frame rate: ``gaussian-cv`` — gaps filled linearly, then each channel smoothed by the
  Gaussian whose width leave-one-out cross-validation picks (``adaptive_smooth.cv_gaussian``), from none (clean
  or fast motion keeps its samples) to 16 frames, at most 0.53 s (heavy noise on slow motion). The networks are
  trained on one skeleton and frame rate each (their filters count frames). It replaced ``gaussian-58ms+check``
  (session 23, rule and figures in ``benchmarks/results/gaussian_cv.md``), which made lightly noisy fast motion
  worse than its input.

``mocapnet clean`` (no ``--method``) reports which one ran and why; ``--method ebf`` still asks for the
network and fails with a clear message on a skeleton without one.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mocapnet.methods.neural import shipped_methods
from mocapnet.methods.registry import MethodContext, build_method, register
from mocapnet.motion import Motion, Skeleton
from mocapnet.nn.variants import same_rate

#: What ``auto`` runs on a skeleton without a shipped network.
FALLBACK = "gaussian-cv"
#: Below this rate (frames/s) ``auto`` smooths nothing: frames a tenth of a second or more apart are keyframes or a
#: subsampled take, too sparse to tell noise from motion (gaps are bridged linearly, ``lerp``).
MIN_SMOOTH_FPS = 10.0


def auto_plan(skeleton: Skeleton, fps: float, has_gaps: bool) -> tuple[str, str]:
    """``(method, reason)``: what ``auto`` runs on a clip of ``skeleton`` at ``fps`` frames/s (with samples to
    fill when ``has_gaps``), and why, in words for a report. A network counts when its index entry's training
    rate is the clip's (``variants.same_rate``; an entry without a rate counts)."""
    every = shipped_methods(skeleton)
    shipped = {m: e for m, e in every.items() if same_rate(fps, e.get("fps"))}
    if "ebf" in shipped:
        corpus = shipped["ebf"]["corpus"]
        if has_gaps and "ebd" in shipped:
            return "ebd+ebf", f"EBD and EBF shipped for this skeleton ({corpus})"
        gaps = "; no EBD shipped for this skeleton and frame rate: gaps bridged linearly" if has_gaps else ""
        return "ebf", f"EBF shipped for this skeleton ({corpus}){gaps}"
    if fps < MIN_SMOOTH_FPS:
        sparse = f"at {fps:g} fps frames are {1.0 / fps:.3g} s apart, too sparse to tell noise from motion"
        return "lerp", sparse + ": samples kept" + (", gaps bridged linearly" if has_gaps else "")
    if other := every.get("ebf"):
        trained = f"the EBF shipped for this skeleton ({other['corpus']}) was trained at {other['fps']:g} fps"
        return FALLBACK, f"{trained}, this clip is at {fps:g} fps"
    return FALLBACK, f"no EBF shipped for this skeleton, {skeleton.describe()}"


@register(
    "auto",
    "angles",
    help="the EBF shipped for the skeleton and frame rate (ebd+ebf when there are gaps and an EBD is shipped); "
    f"on any other skeleton or rate {FALLBACK} (per-channel Gaussian width by cross-validation); mocapnet clean's "
    "default for BVH",
)
def _auto(context: MethodContext) -> Callable[[Motion, np.ndarray], np.ndarray]:
    built: dict[str, Callable] = {}

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        method, _ = auto_plan(noisy.skeleton, noisy.fps, bool(mask.any()))
        if method not in built:
            built[method] = build_method(method, context, space="angles").clean
        return built[method](noisy, mask)

    return clean
