"""Running trained cleaners on motions: loading a checkpoint of any of the networks, cleaning a whole clip in
sequence or windowed mode, and frame-by-frame streaming (windowed mode, EBF).

Modes (same weights):

* ``"sequence"``: one bidirectional LSTM pass over the whole clip (the fastest offline);
* ``"windowed"``: the output at frame t depends only on frames t-15 … t+15 (EBD: ± 15 steps of 4 frames),
  shifted inside the clip at its ends, as a streaming cleaner with a fixed lookahead would compute it.
  On a clip no longer than one window the two modes are the same computation.
"""

from __future__ import annotations

import os
import warnings
from collections import deque
from os import PathLike

import numpy as np
import torch

from mocapnet.fill import lerp_fill
from mocapnet.io.atomic import MocapFileError
from mocapnet.motion import Skeleton
from mocapnet.nn.base import CleanerModule
from mocapnet.nn.checkpoints import read_checkpoint
from mocapnet.nn.ebd import EBD
from mocapnet.nn.ebf import EBF
from mocapnet.nn.features import (
    context_chain,
    context_matrix,
    relative_rotvec,
    root_angular_velocity,
    scored_index,
    topology_hash,
)
from mocapnet.nn.window_mlp import WindowMLP
from mocapnet.threads import pin_threads

MODES = ("sequence", "windowed")
MODEL_CLASSES: dict[str, type[CleanerModule]] = {"EBF": EBF, "EBD": EBD, "WindowMLP": WindowMLP}


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
    if fps and hp.fps and abs(fps / hp.fps - 1.0) > 0.01:
        warnings.warn(f"{source} was trained at {hp.fps:g} fps; this motion is at {fps:g} fps", stacklevel=2)


#: Sequence mode on long clips: the clip is cut into windows of ``CHUNK + 2·OVERLAP`` frames run as one batch
#: (``GROUP_FRAMES`` frames at a time); each keeps its central ``CHUNK`` frames. Memory is O(T·C) and the
#: batched LSTM is several times faster than one pass over T steps; the outputs differ from a single pass
#: by what the recurrent state carries over more than ``OVERLAP`` frames (shipped CMU models on the 2,752-frame
#: sample, noise+gaps: EBF max 0.010°, RMS 6e-5°; EBD max 0.056°, RMS 5e-4°; tests/nn/test_models.py).
CHUNK = 512
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
    """Sequence-mode output ``[T, C]`` for one clip given as a batch of 1 (``[1, T, ·]`` tensors), in
    overlapping chunks (``CHUNK``, ``OVERLAP``) when the clip is longer than one window."""
    n = batch["filled"].shape[1]
    if n <= CHUNK + 2 * OVERLAP:
        return model.predict_batch(batch)[0]
    starts, cores, width = chunk_starts(n)
    out = batch["filled"].new_empty(n, batch["filled"].shape[2])
    per_group = max(1, GROUP_FRAMES // width)
    frames = torch.arange(width)
    for g in range(0, len(starts), per_group):
        ws = torch.as_tensor(starts[g : g + per_group])
        rows = ws[:, None] + frames  # [G, W]
        pred = model.predict_batch({k: v[0][rows] for k, v in batch.items()})  # [G, W, C]
        for i, (w0, c0) in enumerate(zip(starts[g : g + per_group], cores[g : g + per_group])):
            c1 = min(int(c0) + CHUNK, n)
            out[c0:c1] = pred[i, c0 - w0 : c1 - w0]
    return out


@torch.inference_mode()
def clean_channels(
    model: CleanerModule, channels: np.ndarray, mask: np.ndarray, skeleton: Skeleton, fps: float, mode: str = "sequence"
) -> np.ndarray:
    """Clean one clip: ``channels [T, C]`` (degrees, NaN where ``mask [T, C]`` is True) → ``[T, C]``.

    Gaps are first filled by linear interpolation; only the scored channels change (EBD changes only their
    missing samples). ``mode``: ``"sequence"`` (in overlapping chunks on long clips, ``predict_sequence``) or
    ``"windowed"`` (module docstring).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    result = lerp_fill(channels, mask)
    idx = scored_index(skeleton)
    x = torch.as_tensor(result[:, idx], dtype=torch.float32)
    m = torch.as_tensor(mask[:, idx], dtype=torch.bool)
    w = torch.as_tensor(root_angular_velocity(skeleton, result, fps), dtype=torch.float32)
    if mode == "sequence":
        out = predict_sequence(model, {"filled": x[None], "mask": m[None], "angvel": w[None]})
    else:
        out = model.windowed(x, m, w)
    del x, w
    if isinstance(model, EBD):
        scored = result[:, idx]
        result[:, idx] = np.where(mask[:, idx], out.numpy(), scored)
    else:
        result[:, idx] = out.numpy()
    return result


class EBFStream:
    """Frame-by-frame EBF cleaning with a fixed lookahead of ``half`` frames (windowed mode).

    ``push(frame)`` takes one frame of channels ``[C]`` (degrees, no gaps) and returns the frames that became
    final, as a list of ``(frame index, cleaned channels [C])``: from frame ``2·half`` on, one per call
    (frame ``t - half``; the first call that completes a window returns frames 0 … half). ``flush()`` returns
    the last ``half`` frames at the end of the stream. The results equal ``clean_channels(...,
    mode="windowed")`` on the whole clip.
    """

    def __init__(self, model: EBF, skeleton: Skeleton, fps: float) -> None:
        if not isinstance(model, EBF):
            raise TypeError("EBFStream streams EBF (and BF) models")
        check_skeleton(model, skeleton, fps=fps)
        self.model, self.skeleton, self.fps = model, skeleton, fps
        self.half = model.hparams.half
        self.width = 2 * self.half + 1
        self.idx = scored_index(skeleton)
        self.frames: deque[np.ndarray] = deque(maxlen=self.width)
        self.scored: deque[torch.Tensor] = deque(maxlen=self.width)
        self.codes: deque[torch.Tensor] = deque(maxlen=self.width)
        self.count = 0
        self._prev_rot: np.ndarray | None = None
        self._chain = context_chain(skeleton)
        self._last_window: tuple[torch.Tensor, torch.Tensor] | None = None

    def _encode(self, scored: torch.Tensor, angvel: np.ndarray) -> torch.Tensor:
        w = torch.as_tensor(angvel, dtype=torch.float32)[None, None]
        return self.model.encoder(self.model.features(scored[None, None], w))[0, 0]

    def _emit(self, positions: list[int], lstm_out: torch.Tensor, window: torch.Tensor) -> list[tuple[int, np.ndarray]]:
        """Cleaned frames at ``positions`` of the current window (``window [W, C]`` scored channels)."""
        model, h = self.model, self.half
        params = model.head(lstm_out[positions])  # [n, P]
        weights = model.filter_weights(params[None])[0]  # [C, n, K]
        pos = torch.as_tensor(positions)
        taps = (pos[:, None] + torch.arange(-h, h + 1)).clamp(0, len(window) - 1)  # [n, K]
        values = model.debias((window[taps].permute(2, 0, 1) * weights).sum(-1).T, params)  # [n, C]
        first = self.count - len(self.frames)
        out = []
        for p, v in zip(positions, values.double().numpy()):
            frame = self.frames[p].copy()
            frame[self.idx] = v
            out.append((first + p, frame))
        return out

    @torch.inference_mode()
    def _window(self) -> tuple[torch.Tensor, torch.Tensor]:
        lstm_out, _ = self.model.blstm.lstm(torch.stack(list(self.codes))[None])
        window = torch.stack(list(self.scored))
        self._last_window = (lstm_out[0], window)
        return self._last_window

    @torch.inference_mode()
    def push(self, frame: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Add frame ``count`` (channels ``[C]``, degrees); return the frames that became final."""
        frame = np.asarray(frame, dtype=np.float64)
        rot = context_matrix(self._chain, frame)
        self.frames.append(frame)
        self.scored.append(torch.as_tensor(frame[self.idx], dtype=torch.float32))
        self.count += 1
        if self._prev_rot is None:
            self._prev_rot = rot
            return []
        angvel = relative_rotvec(self._prev_rot, rot) * self.fps
        self._prev_rot = rot
        if self.count == 2:
            self.codes.append(self._encode(self.scored[0], angvel))
        self.codes.append(self._encode(self.scored[-1], angvel))
        if self.count < self.width:
            return []
        lstm_out, window = self._window()
        positions = list(range(self.half + 1)) if self.count == self.width else [self.half]
        return self._emit(positions, lstm_out, window)

    @torch.inference_mode()
    def flush(self) -> list[tuple[int, np.ndarray]]:
        """End of stream: the frames not returned yet."""
        if self.count == 0:
            return []
        if self.count == 1:
            self.codes.append(self._encode(self.scored[0], np.zeros(3)))
        if self.count < self.width:
            lstm_out, window = self._window()
            return self._emit(list(range(self.count)), lstm_out, window)
        lstm_out, window = self._last_window
        return self._emit(list(range(self.half + 1, self.width)), lstm_out, window)
