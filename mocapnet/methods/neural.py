"""The learned cleaners as angle-space methods: ``ebf`` and its named variants, ``ebd``, ``ebd+ebf``, and the
ablations ``bf``, ``nn``.

EBF variants (issue 11): ``ebf-paper`` the paper's network (σ-only Gaussian filter per channel and frame, no
bias); ``ebf-bias`` the same with a per-channel bias (residual) output; ``ebf-free`` a free-shape kernel
(softmax over the 31 taps, with or without the bias output); ``ebf`` the best shipped variant for the clip's
skeleton (``"ebf": true`` in ``mocapnet/checkpoints/index.json``; its recipe is in ``mocapnet methods``).
A variant name given a checkpoint checks that the checkpoint is that variant; ``ebf=FILE`` takes any.

    --method ebf                       the checkpoint shipped for the clip's skeleton (mocapnet/checkpoints)
    --method ebf=run/best.ckpt         a trained checkpoint
    --method ebd+ebf=ebd.ckpt,ebf.ckpt gap filling by EBD, then denoising by EBF
    --method ebf:mode=windowed         streaming-equivalent windowed mode (default: sequence)
    --method ebf:mode=windowed,checkpoints=run/best.ckpt   both
    --method ebd+ebf=ebd.ckpt,ebf.ckpt:mode=windowed       both, with two checkpoints

Gaps are filled by linear interpolation before any network; EBD's fill of each gap is then blended with the
better interpolation for its length and self-checked (``mocapnet.nn.ebd.blend_gaps``).
Only the scored channels change. torch is imported when a method is built, never by ``import mocapnet``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from mocapnet.methods.registry import MethodContext, register
from mocapnet.motion import Motion
from mocapnet.nn.variants import VARIANTS, accepts, method_of

_HELP = "{what}; checkpoint: NAME=PATH, default: the shipped one for the skeleton; option mode=sequence|windowed"
_INDEX = Path(__file__).resolve().parents[1] / "checkpoints" / "index.json"


def _resolver(method: str, path: str | None) -> Callable[[Motion], object]:
    """A function giving the loaded model for a motion: from ``path`` (loaded now, so a bad path fails at
    build time) or the shipped checkpoint of ``method`` for the motion's skeleton (loaded once per skeleton)."""
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import check_skeleton, load_model

    if path is not None:
        if not Path(path).is_file():
            raise FileNotFoundError(f"{method}: checkpoint {path} not found")
        model = load_model(path)
        kind = method_of(type(model).__name__, dict(model.hparams))
        if not accepts(method, kind):
            raise ValueError(f"{method}: {path} holds a {type(model).__name__} network ({kind}), not {method}")

        def given(motion: Motion) -> object:
            check_skeleton(model, motion.skeleton, f"checkpoint {path}", motion.fps)
            return model

        return given
    cache: dict[tuple, object] = {}

    def shipped(motion: Motion) -> object:
        key = motion.skeleton.topology()
        if key not in cache:
            ckpt = shipped_checkpoint(method, motion.skeleton)
            cache[key] = load_model(ckpt)
            check_skeleton(cache[key], motion.skeleton, f"shipped checkpoint {ckpt.name}", motion.fps)
        return cache[key]

    return shipped


def _shipped_ebf_recipes() -> str:
    """What ``ebf`` runs, per corpus, from the shipped index (read as JSON; no torch)."""
    if not _INDEX.exists():
        return "none shipped"
    entries = [e for e in json.loads(_INDEX.read_text())["checkpoints"] if e.get("ebf")]
    return "; ".join(f"{e['corpus']}: {e['method']} ({e.get('recipe', '')}, {e.get('budget', '')})" for e in entries)


def _paths(checkpoints: Sequence[str] | str) -> list[str]:
    """``checkpoints`` as a list (the ``name:checkpoints=path`` option form gives one string)."""
    return [checkpoints] if isinstance(checkpoints, str) else list(checkpoints)


def _check_mode(mode: str) -> str:
    from mocapnet.nn.infer import MODES

    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


def _single(method: str):
    def factory(
        context: MethodContext,
        checkpoints: Sequence[str] | str = (),
        mode: str = "sequence",
        limit: float | None = None,
    ):
        """``limit``: EBF's self-check factor (``infer.limit_change``; default: the checkpoint's, 0: off)."""
        from mocapnet.nn.infer import clean_channels

        checkpoints = _paths(checkpoints)
        if len(checkpoints) > 1:
            raise ValueError(f"{method} takes one checkpoint, got {len(checkpoints)}")
        resolve = _resolver(method, checkpoints[0] if checkpoints else None)
        _check_mode(mode)
        if limit is not None and not (isinstance(limit, (int, float)) and limit >= 0):
            raise ValueError(f"{method}: limit must be a number >= 0, got {limit!r}")

        def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
            model = resolve(noisy)
            return clean_channels(model, noisy.channels, mask, noisy.skeleton, noisy.fps, mode, change_limit=limit)

        return clean

    return factory


_WHAT = {v.name: v.what for v in VARIANTS}
_WHAT["ebf"] += f": {_shipped_ebf_recipes()}"
for _name, _what in _WHAT.items():
    register(_name, "angles", help=_HELP.format(what=_what))(_single(_name))


@register("ebd+ebf", "angles", help=_HELP.format(what="EBD fills gaps, then EBF denoises; checkpoints: EBD,EBF"))
def _ebd_ebf(context: MethodContext, checkpoints: Sequence[str] | str = (), mode: str = "sequence"):
    from mocapnet.nn.infer import clean_channels

    checkpoints = _paths(checkpoints)
    if len(checkpoints) not in (0, 2):
        raise ValueError(f"ebd+ebf takes two checkpoints (EBD,EBF), got {len(checkpoints)}")
    ebd = _resolver("ebd", checkpoints[0] if checkpoints else None)
    ebf = _resolver("ebf", checkpoints[1] if checkpoints else None)
    _check_mode(mode)

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        # The network's own fill: blending with interpolation (ebd.blend_gaps) assumes clean observed samples
        # and made noise+gaps worse on bandai2 fold 1 (gap error 7.49° blended vs 4.16° raw).
        filled = clean_channels(ebd(noisy), noisy.channels, mask, noisy.skeleton, noisy.fps, mode, gap_blend=None)
        no_gaps = np.zeros_like(mask)
        return clean_channels(ebf(noisy), filled, no_gaps, noisy.skeleton, noisy.fps, mode)

    return clean
