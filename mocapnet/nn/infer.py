"""Running trained cleaners on motions: loading a checkpoint of any of the networks, cleaning a whole clip in
sequence or windowed mode, and EBF's self-check (frame-by-frame streaming is ``mocapnet.nn.stream``).

Modes (same weights):

* ``"sequence"``: one bidirectional LSTM pass over the whole clip (the fastest offline);
* ``"windowed"``: the output at frame t depends only on frames t-15 … t+15 (EBD: ± 15 steps of 4 frames),
  shifted inside the clip at its ends, as a streaming cleaner with a fixed lookahead would compute it.
  On a clip no longer than one window the two modes are the same computation.
"""

from __future__ import annotations

import importlib
import os
import warnings
from os import PathLike

import numpy as np
import torch

from mocapnet.fill import lerp_fill
from mocapnet.io.atomic import MocapFileError
from mocapnet.motion import Skeleton
from mocapnet.nn.base import NORM_KEYS, CleanerModule, clip_statistics, uses_clip_statistics
from mocapnet.nn.checkpoints import read_checkpoint
from mocapnet.nn.ebd import EBD, GapBlend, blend_gaps, rehearse
from mocapnet.nn.ebf import EBF
from mocapnet.nn.features import root_angular_velocity, scored_index, topology_hash
from mocapnet.nn.variants import MODEL_MODULES, same_rate
from mocapnet.selfcheck import limit_change
from mocapnet.threads import pin_threads

MODES = ("sequence", "windowed")
MODEL_CLASSES: dict[str, type[CleanerModule]] = {
    name: getattr(importlib.import_module(module), name) for name, module in MODEL_MODULES.items()
}


def inference_threads() -> int:
    """Pin torch and BLAS to the process's thread count (``mocapnet.threads``): what ``OMP_NUM_THREADS`` says
    (``pin_threads`` and the user set it), else ``$MOCAPNET_THREADS``, else 1. Inference is fastest that way on
    a shared machine (no busy-waiting pools). Returns the count."""
    text = os.environ.get("OMP_NUM_THREADS", "")
    return pin_threads(int(text) if text.isdigit() and int(text) > 0 else None)


def load_model(path: str | PathLike) -> CleanerModule:
    """Load a checkpoint written by ``mocapnet.nn.train`` (or a shipped one) in eval mode on the CPU; the class
    is read from the checkpoint. The file is read as data (``checkpoints.read_checkpoint``); MocapFileError
    naming the file when it is not a mocapnet network checkpoint or its weights do not fit the network."""
    ckpt = read_checkpoint(path)
    inference_threads()
    name = ckpt.get("mocapnet_model")
    if name not in MODEL_CLASSES or not isinstance(ckpt.get("hyper_parameters"), dict):
        raise MocapFileError(f"{path}: not a mocapnet network checkpoint (model class {name!r})")
    try:
        model = MODEL_CLASSES[name](**ckpt["hyper_parameters"])
        model.load_state_dict(ckpt["state_dict"])
    except (TypeError, KeyError, RuntimeError, ValueError) as exc:
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise MocapFileError(f"{path}: {name} checkpoint does not fit the network: {reason}") from None
    torch.set_flush_denormal(True)
    return model.eval()


def check_skeleton(model: CleanerModule, skeleton: Skeleton, source: str = "checkpoint", fps: float = 0.0) -> None:
    """Raise ValueError naming both skeletons when ``model`` was trained on another topology; warn when the
    frame rate ``fps`` (if given) differs from the training rate (filter widths are in frames)."""
    mine = topology_hash(skeleton)
    hp = model.hparams
    if hp.skeleton_hash != mine:
        raise ValueError(
            f"{source} was trained on corpus {hp.corpus!r} (skeleton {hp.skeleton_hash}, {hp.n_channels} scored "
            f"channels); this motion's skeleton is {skeleton.describe()} ({mine}, "
            f"{int(skeleton.scored_mask.sum())} scored channels)"
        )
    if not same_rate(fps, hp.fps):
        warnings.warn(f"{source} was trained at {hp.fps:g} fps; this motion is at {fps:g} fps", stacklevel=2)


#: Sequence mode on long clips: the clip is cut into windows of ``CHUNK + 2·OVERLAP`` frames run as one batch
#: (``GROUP_FRAMES`` frames at a time); each keeps its central ``CHUNK`` frames. Memory is O(T·C) and the
#: batched LSTM is several times faster than one pass over T steps; the outputs differ from a single pass
#: by what the recurrent state carries over more than ``OVERLAP`` frames (shipped CMU models on the 2,752-frame
#: sample, noise+gaps: EBF max 0.0024°, RMS 3e-5°; EBD max 0.018°, RMS 1e-4°; tests/nn/test_models.py). 1024-frame
#: cores recompute 25 % of the frames (512-frame cores: 50 %, 1.15x slower for a free-kernel EBF).
CHUNK = 1024
OVERLAP = 128
GROUP_FRAMES = 32768


def chunk_starts(n_frames: int, chunk: int = CHUNK, overlap: int = OVERLAP) -> tuple[np.ndarray, np.ndarray, int]:
    """``(window starts, kept-core starts, window length)`` covering ``n_frames``: window i spans
    ``[ws_i, ws_i + W)`` with ``W = min(chunk + 2·overlap, n_frames)`` and supplies frames
    ``[cs_i, cs_{i+1})`` (``cs_i = i·chunk``), at least ``overlap`` frames from its ends except at the clip's."""
    width = min(chunk + 2 * overlap, n_frames)
    cores = np.arange(0, n_frames, chunk)
    return np.clip(cores - overlap, 0, n_frames - width), cores, width


def predict_sequence(model: CleanerModule, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Sequence-mode output ``[T, C]`` for one clip given as a batch of 1 (``[1, T, ·]`` tensors; the clip's
    statistics ``NORM_KEYS`` ``[1, 1, ·]`` when present), in overlapping chunks (``CHUNK``, ``OVERLAP``) when the
    clip is longer than one window; every chunk keeps the whole clip's statistics. An EBF runs only its LSTM
    on the overlaps (``EBF.predict_chunked``, the same output as ``predict_windows``; 1.2x less CPU time for
    the shipped bandai2 ``ebf`` on 10,000 frames)."""
    n = batch["filled"].shape[1]
    if n <= CHUNK + 2 * OVERLAP:
        return model.predict_batch(batch)[0]
    starts, cores, width = chunk_starts(n)
    per_group = max(1, GROUP_FRAMES // width)
    if isinstance(model, EBF):
        return model.predict_chunked(batch, starts, cores, width, per_group)
    return predict_windows(model, batch, starts, cores, width, per_group)


def predict_windows(
    model: CleanerModule,
    batch: dict[str, torch.Tensor],
    starts: np.ndarray,
    cores: np.ndarray,
    width: int,
    per_group: int,
) -> torch.Tensor:
    """``predict_sequence`` of any network: ``model.predict_batch`` on every window ``[starts_i, starts_i +
    width)`` (``chunk_starts``), ``per_group`` windows per batch, each keeping its core ``[cores_i,
    cores_{i+1})`` → ``[T, C]``."""
    n = batch["filled"].shape[1]
    chunk = int(cores[1] - cores[0]) if len(cores) > 1 else n
    out = batch["filled"].new_empty(n, batch["filled"].shape[2])
    frames = torch.arange(width)
    for g in range(0, len(starts), per_group):
        ws = torch.as_tensor(starts[g : g + per_group])
        rows = ws[:, None] + frames  # [G, W]
        chunks = {k: v.expand(len(rows), -1, -1) if k in NORM_KEYS else v[0][rows] for k, v in batch.items()}
        pred = model.predict_batch(chunks)  # [G, W, C]
        for i, (w0, c0) in enumerate(zip(starts[g : g + per_group], cores[g : g + per_group])):
            c1 = min(int(c0) + chunk, n)
            out[c0:c1] = pred[i, c0 - w0 : c1 - w0]
    return out


@torch.inference_mode()
def clean_channels(
    model: CleanerModule,
    channels: np.ndarray,
    mask: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    mode: str = "sequence",
    gap_blend: GapBlend | str | None = "checkpoint",
    change_limit: float | None = None,
) -> np.ndarray:
    """Clean one clip: ``channels [T, C]`` (degrees, NaN where ``mask [T, C]`` is True) → ``[T, C]``.

    Gaps are first filled by linear interpolation (an EBD: by the interpolation it was trained to correct,
    ``EBD.interpolate``); only the scored channels change (EBD changes only their
    missing samples). ``mode``: ``"sequence"`` (in overlapping chunks on long clips, ``predict_sequence``) or
    ``"windowed"`` (module docstring). ``gap_blend``: how EBD's fill is blended with interpolation and
    self-checked (``ebd.blend_gaps``, after ``ebd.rehearse`` when its ``rehearsals`` > 0: one more network pass
    with stand-in gaps); ``"checkpoint"``: the setting stored with the network (``EBD.blend``); None keeps the
    network's fill as it comes. ``change_limit``: EBF's
    self-check factor (``limit_change``; None: the checkpoint's ``change_limit`` hyper-parameter, 0: none).
    Angles are taken as continuous along time (``fill.unwrap_observed``); observed samples an EBD keeps bit for bit.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if isinstance(gap_blend, str) and gap_blend != "checkpoint":
        raise ValueError(f"gap_blend must be a GapBlend, 'checkpoint' or None, got {gap_blend!r}")
    idx = scored_index(skeleton)
    result, out = _network_output(model, channels, mask, idx, skeleton, fps, mode)
    if isinstance(model, EBD):
        scored = result[:, idx]
        if gap_blend is None:
            result[:, idx] = np.where(mask[:, idx], out.numpy(), scored)
        else:
            blend = model.blend() if gap_blend == "checkpoint" else gap_blend

            def network(scored_mask: np.ndarray) -> np.ndarray:  # the fill with more samples hidden (rehearse)
                more = mask.copy()
                more[:, idx] = scored_mask
                trial = channels.copy()
                trial[more] = np.nan
                return _network_output(model, trial, more, idx, skeleton, fps, mode)[1].numpy()

            trusted = rehearse(scored, mask[:, idx], fps, blend, network) if blend.rehearsals else None
            result[:, idx] = blend_gaps(scored, mask[:, idx], out.numpy(), fps, blend, trusted=trusted)[0]
    else:
        limit = float(model.hparams.get("change_limit", 0.0)) if change_limit is None else change_limit
        cleaned = out.numpy().astype(np.float64)
        result[:, idx] = limit_change(result[:, idx], cleaned, limit) if limit > 0 else cleaned
    return result


def _network_output(
    model: CleanerModule,
    channels: np.ndarray,
    mask: np.ndarray,
    idx: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    mode: str,
) -> tuple[np.ndarray, torch.Tensor]:
    """``(interpolated channels [T, C_all], the network's output [T, C] for the scored channels idx)`` of one
    clip (``clean_channels``'s arguments)."""
    result = model.interpolate(channels, mask, fps) if isinstance(model, EBD) else lerp_fill(channels, mask)
    x = torch.as_tensor(np.ascontiguousarray(result[:, idx]), dtype=torch.float32)  # [:, idx] is column-major
    m = torch.as_tensor(mask[:, idx], dtype=torch.bool)
    w = torch.as_tensor(root_angular_velocity(skeleton, result, fps), dtype=torch.float32)
    if mode == "sequence":
        batch = {"filled": x[None], "mask": m[None], "angvel": w[None]}
        if uses_clip_statistics(model):
            batch |= clip_statistics(x[None], w[None])
        return result, predict_sequence(model, batch)
    return result, model.windowed(x, m, w)
