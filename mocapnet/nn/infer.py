"""Running trained cleaners on motions: loading a checkpoint of any of the networks, cleaning a whole clip in
sequence or windowed mode, and frame-by-frame streaming (windowed mode, EBF).

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
from collections import deque
from os import PathLike

import numpy as np
import torch

from mocapnet.fill import lerp_fill
from mocapnet.io.atomic import MocapFileError
from mocapnet.motion import Skeleton
from mocapnet.nn.base import NORM_KEYS, CleanerModule, clip_statistics
from mocapnet.nn.checkpoints import read_checkpoint
from mocapnet.nn.ebd import EBD, GAP_BLEND, GapBlend, blend_gaps
from mocapnet.nn.ebf import EBF
from mocapnet.nn.features import (
    MIN_SCALE_DEG,
    context_chain,
    context_matrix,
    relative_rotvec,
    root_angular_velocity,
    scored_index,
    topology_hash,
)
from mocapnet.nn.variants import MODEL_MODULES
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
    if fps and hp.fps and abs(fps / hp.fps - 1.0) > 0.01:
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
    clip is longer than one window; every chunk keeps the whole clip's statistics."""
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
        chunks = {k: v.expand(len(rows), -1, -1) if k in NORM_KEYS else v[0][rows] for k, v in batch.items()}
        pred = model.predict_batch(chunks)  # [G, W, C]
        for i, (w0, c0) in enumerate(zip(starts[g : g + per_group], cores[g : g + per_group])):
            c1 = min(int(c0) + CHUNK, n)
            out[c0:c1] = pred[i, c0 - w0 : c1 - w0]
    return out


#: Columns the self-check handles at a time (its temporaries are ``[T, COLUMN_BLOCK]``: O(T) memory).
COLUMN_BLOCK = 8


def noise_level(x: np.ndarray) -> np.ndarray:
    """Standard deviation ``[C]`` (degrees) of white noise that ``x [T, C]`` (degrees) shows, from its second
    differences (``6σ²`` for white noise): ``1.4826·MAD / √6``, robust to the motion's own curvature at a few
    frames and to spikes; the motion's curvature can only raise it. Zeros for fewer than 3 frames."""
    out = np.zeros(x.shape[1])
    if len(x) < 3:
        return out
    for c in range(0, x.shape[1], COLUMN_BLOCK):
        d2 = np.diff(np.unwrap(x[:, c : c + COLUMN_BLOCK], period=360.0, axis=0), n=2, axis=0)
        d2 -= np.median(d2, axis=0)
        out[c : c + COLUMN_BLOCK] = 1.4826 * np.median(np.abs(d2, out=d2), axis=0) / np.sqrt(6.0)
    return out


def limit_change(noisy: np.ndarray, cleaned: np.ndarray, factor: float) -> np.ndarray:
    """The self-check: ``cleaned [T, C]`` moved back toward ``noisy [T, C]`` (degrees) on each channel whose RMS
    change exceeds ``factor`` × its ``noise_level``, so that it changes by exactly that much. A denoiser has no
    business changing a channel by much more than the noise it shows (on nearly clean input a learned filter
    otherwise smooths away real motion). Returns a new array; works ``COLUMN_BLOCK`` columns at a time."""
    cap = factor * noise_level(noisy)
    out = np.empty(np.broadcast_shapes(noisy.shape, cleaned.shape))
    for c in range(0, out.shape[1], COLUMN_BLOCK):
        cols = slice(c, c + COLUMN_BLOCK)
        change = (cleaned[:, cols] - noisy[:, cols] + 180.0) % 360.0 - 180.0
        rms = np.sqrt(np.mean(change**2, axis=0))
        change *= np.where(rms > cap[cols], cap[cols] / np.maximum(rms, 1e-12), 1.0)
        out[:, cols] = noisy[:, cols] + change
    return out


@torch.inference_mode()
def clean_channels(
    model: CleanerModule,
    channels: np.ndarray,
    mask: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    mode: str = "sequence",
    gap_blend: GapBlend | None = GAP_BLEND,
    change_limit: float | None = None,
) -> np.ndarray:
    """Clean one clip: ``channels [T, C]`` (degrees, NaN where ``mask [T, C]`` is True) → ``[T, C]``.

    Gaps are first filled by linear interpolation (an EBD: by the interpolation it was trained to correct,
    ``EBD.interpolate``); only the scored channels change (EBD changes only their
    missing samples). ``mode``: ``"sequence"`` (in overlapping chunks on long clips, ``predict_sequence``) or
    ``"windowed"`` (module docstring). ``gap_blend``: how EBD's fill is blended with interpolation and
    self-checked (``ebd.blend_gaps``); None keeps the network's fill as it comes. ``change_limit``: EBF's
    self-check factor (``limit_change``; None: the checkpoint's ``change_limit`` hyper-parameter, 0: none).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    result = model.interpolate(channels, mask, fps) if isinstance(model, EBD) else lerp_fill(channels, mask)
    idx = scored_index(skeleton)
    x = torch.as_tensor(result[:, idx], dtype=torch.float32)
    m = torch.as_tensor(mask[:, idx], dtype=torch.bool)
    w = torch.as_tensor(root_angular_velocity(skeleton, result, fps), dtype=torch.float32)
    if mode == "sequence":
        batch = {"filled": x[None], "mask": m[None], "angvel": w[None]}
        if model.hparams.get("norm", "corpus") == "clip":
            batch |= clip_statistics(x[None], w[None])
        out = predict_sequence(model, batch)
    else:
        out = model.windowed(x, m, w)
    del x, w
    if isinstance(model, EBD):
        scored = result[:, idx]
        if gap_blend is None:
            result[:, idx] = np.where(mask[:, idx], out.numpy(), scored)
        else:
            result[:, idx] = blend_gaps(scored, mask[:, idx], out.numpy(), fps, gap_blend)[0]
    else:
        limit = float(model.hparams.get("change_limit", 0.0)) if change_limit is None else change_limit
        cleaned = out.numpy().astype(np.float64)
        result[:, idx] = limit_change(result[:, idx], cleaned, limit) if limit > 0 else cleaned
    return result


class _CentreKernel:
    """EBF's windowed-mode output for the centre frame of a full window, in numpy float32 (the streaming
    cleaner's steady state: one call per frame, so per-call overhead is what counts).

    Savings over running ``nn.LSTM`` on the window: layer 1's input projection is computed once per frame
    (``project``) and kept; both directions of a layer step together (one batched product per step, into
    preallocated buffers whose gate views are made once); the gate rows are reordered to (cell, forget,
    input, output) and those of the three sigmoid gates halved, so one tanh covers all four
    (``σ(x) = (1 + tanh(x/2)) / 2``), and the cell state sits just before the gates, so ``f·c`` and ``i·g`` are
    one product of adjacent pairs; layer 2 runs only the steps its centre output depends on (``half + 1``
    each way instead of ``2·half + 1``); the encoder, head and filter touch one frame. Same arithmetic as the
    torch modules (float32 rounding apart).
    """

    def __init__(self, model: EBF) -> None:
        lstm = model.blstm.lstm
        hid = lstm.hidden_size
        # torch's gate order is (i, f, g, o); here (g, f, i, o)
        order = np.concatenate(
            [np.arange(2 * hid, 3 * hid), np.arange(hid, 2 * hid), np.arange(hid), np.arange(3 * hid, 4 * hid)]
        )
        half_sig = np.where(np.arange(4 * hid) >= hid, 0.5, 1.0).astype(np.float32)

        def both(name: str, layer: int) -> np.ndarray:
            fwd, bwd = getattr(lstm, f"{name}_l{layer}"), getattr(lstm, f"{name}_l{layer}_reverse")
            w = np.stack([fwd.detach().numpy(), bwd.detach().numpy()]).astype(np.float32)[:, order]
            return w * (half_sig[:, None] if w.ndim == 3 else half_sig)

        self.wih = [both("weight_ih", layer) for layer in (0, 1)]  # [2, 4H, in], gates (i, f, o, g)
        self.whh_t = [np.ascontiguousarray(both("weight_hh", layer).transpose(0, 2, 1)) for layer in (0, 1)]
        self.bias = [both("bias_ih", layer) + both("bias_hh", layer) for layer in (0, 1)]  # [2, 4H]
        self.wih1_t = [np.ascontiguousarray(self.wih[1][d].T) for d in (0, 1)]  # [2H, 4H] per direction
        self.wih0_t = np.ascontiguousarray(self.wih[0].transpose(2, 0, 1).reshape(self.wih[0].shape[2], -1))
        self.bias0 = self.bias[0].reshape(-1)  # [8H]: both directions, as the columns of wih0_t
        self.hidden = hid
        self.encoder = _dense_layers(model.encoder)
        self.head = _dense_layers(model.head)
        hp = model.hparams
        self.half, self.n_channels, self.n_filter = hp.half, hp.n_channels, model.n_filter
        self.free, self.has_bias = hp.filter_shape == "free", bool(hp.bias)
        self.bias_bound = float(hp.get("bias_bound", 3.0))
        self.set_stats(model.center.numpy(), model.scale.numpy(), model.angvel_scale.numpy())
        self.taps_sq = (np.arange(-self.half, self.half + 1, dtype=np.float32) ** 2)[None, :]
        width = 2 * self.half + 1
        # step buffers: h, c [2, 1, H]; gates [2, 1, 4H] and views of them; layer-1 outputs [W, 2, 1, H]
        self._h = np.zeros((2, 1, hid), dtype=np.float32)
        self._tmp = np.zeros((2, 1, hid), dtype=np.float32)
        self._prod = np.zeros((2, 1, 2 * hid), dtype=np.float32)
        # [c | g | f | i | o]: the cell state, then the gates (the matmul's output)
        z = self._state = np.zeros((2, 1, 5 * hid), dtype=np.float32)
        self._c, self._gates, self._sig, self._o = z[..., :hid], z[..., hid:], z[..., 2 * hid :], z[..., 4 * hid :]
        self._cg, self._fi = z[..., : 2 * hid], z[..., 2 * hid : 4 * hid]
        self._layer1 = np.zeros((width, 2, 1, hid), dtype=np.float32)
        self._seq = np.zeros((width, 2, 1, 4 * hid), dtype=np.float32)
        self._per_frame = np.zeros((width, 2 * hid), dtype=np.float32)  # layer-1 output per frame
        self._step2 = np.zeros((self.half + 1, 2, 1, 4 * hid), dtype=np.float32)

    @staticmethod
    def usable(model: EBF) -> bool:
        """Whether ``model``'s LSTM has the two layers this kernel computes."""
        return model.blstm.lstm.num_layers == 2 and model.blstm.stride == 1

    def set_stats(self, center: np.ndarray, scale: np.ndarray, angvel_scale: np.ndarray) -> None:
        """The input statistics (``[C]``, ``[C]`` degrees, ``[3]`` rad/s) the next projections use."""
        self.center = np.asarray(center, dtype=np.float32)
        self.scale = np.asarray(scale, dtype=np.float32)
        self.angvel_scale = np.asarray(angvel_scale, dtype=np.float32)

    def project(self, scored: np.ndarray, angvel: np.ndarray) -> np.ndarray:
        """Layer-1 LSTM input projections ``[N, 2, 1, 4H]`` (both directions, biases included) of frames with
        scored channels ``[N, C]`` (degrees) and root angular velocity ``[N, 3]`` (rad/s)."""
        x = np.clip((np.remainder(scored - self.center + 180.0, 360.0) - 180.0) / self.scale, -8.0, 8.0)
        w = np.clip(angvel / self.angvel_scale, -8.0, 8.0)
        code = _run_dense(self.encoder, np.concatenate([x, w], axis=1).astype(np.float32))  # [N, F]
        out = code @ self.wih0_t
        out += self.bias0
        return out.reshape(len(out), 2, 1, -1)

    def _steps(self, proj: np.ndarray, out: np.ndarray | None, layer: int) -> np.ndarray:
        """Run both directions of ``layer`` over ``proj [S, 2, 1, 4H]`` (row s: forward step s, backward step
        s); writes the hidden states into ``out [S, 2, 1, H]`` when given; returns the last ``[2, 1, H]``."""
        c, tmp, gates, sig, o, whh_t = self._c, self._tmp, self._gates, self._sig, self._o, self.whh_t[layer]
        cg, fi, prod, hid = self._cg, self._fi, self._prod, self.hidden
        fc, ig = prod[..., :hid], prod[..., hid:]
        h = self._h
        h.fill(0.0)
        c.fill(0.0)
        for s in range(proj.shape[0]):
            np.matmul(h, whh_t, out=gates)
            gates += proj[s]
            np.tanh(gates, out=gates)  # sigmoid gates: tanh of half their input (weights halved)
            sig *= 0.5
            sig += 0.5
            np.multiply(fi, cg, out=prod)  # [f·c | i·g]
            np.add(fc, ig, out=c)
            np.tanh(c, out=tmp)
            h = self._h if out is None else out[s]
            np.multiply(o, tmp, out=h)
        return h

    def centre(self, proj: np.ndarray, window: np.ndarray) -> np.ndarray:
        """Cleaned scored channels ``[C]`` of the centre frame, from the window's layer-1 projections
        ``[W, 2, 1, 4H]`` (``W = 2·half + 1``) and its scored channels ``[W, C]`` (degrees)."""
        mid, seq, layer1 = self.half, self._seq, self._layer1
        seq[:, 0] = proj[:, 0]  # step s: forward frame s, backward frame W-1-s
        seq[:, 1] = proj[::-1, 1]
        self._steps(seq, layer1, 0)
        per_frame, step2, hid = self._per_frame, self._step2, self.hidden
        per_frame[:, :hid] = layer1[:, 0, 0]
        per_frame[:, hid:] = layer1[::-1, 1, 0]
        np.matmul(per_frame[: mid + 1], self.wih1_t[0], out=step2[:, 0, 0])
        np.matmul(per_frame[mid:][::-1], self.wih1_t[1], out=step2[:, 1, 0])
        step2 += self.bias[1][:, None, :]
        h = self._steps(step2, None, 1)
        params = _run_dense(self.head, h.reshape(1, -1))[0]
        raw = params[: self.n_filter]
        if self.free:
            logits = raw.reshape(self.n_channels, -1)
        else:
            logits = -0.5 * self.taps_sq * np.exp(-2.0 * np.clip(raw, -5.0, 5.0))[:, None]
        weights = np.exp(logits - logits.max(axis=1, keepdims=True))  # [C, K]
        values = np.einsum("ck,kc->c", weights, window) / weights.sum(axis=1)
        if self.has_bias:
            bound = self.bias_bound
            values = values - self.scale * bound * np.tanh(params[self.n_filter :] / bound)
        return values


def _dense_layers(seq: torch.nn.Module) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """``(weightᵀ, bias, tanh after)`` of each Linear of a ``layers.mlp`` (an Identity gives none)."""
    mods = list(seq) if isinstance(seq, torch.nn.Sequential) else []
    out = []
    for i, mod in enumerate(mods):
        if isinstance(mod, torch.nn.Linear):
            tanh = i + 1 < len(mods) and isinstance(mods[i + 1], torch.nn.Tanh)
            weight_t = np.ascontiguousarray(mod.weight.detach().numpy().astype(np.float32).T)
            out.append((weight_t, mod.bias.detach().numpy().astype(np.float32), tanh))
    return out


def _run_dense(layers: list[tuple[np.ndarray, np.ndarray, bool]], x: np.ndarray) -> np.ndarray:
    """Rows ``x [N, F]`` through the dense layers of ``_dense_layers``."""
    for weight_t, bias, tanh in layers:
        x = x @ weight_t
        x += bias
        if tanh:
            np.tanh(x, out=x)
    return x


#: Streaming with ``norm="clip"`` and no statistics given: the running statistics are taken (and the
#: window's layer-1 inputs recomputed) when the stream has seen ``W·2^k`` frames, then every ``STATS_EVERY``.
STATS_EVERY = 1024


class RunningStats:
    """``base.clip_statistics`` of the frames a stream has seen so far, kept as running sums: circular mean per
    channel (sums of sin and cos), std of the values wrapped into ±180° of the first frame's (sums and sums of
    squares), RMS of the root angular velocity. Frames are folded into the sums ``BLOCK`` at a time (one
    vectorised update per block, so a push costs a row copy)."""

    BLOCK = 32

    def __init__(self, n_channels: int) -> None:
        self.n = 0
        self.sin, self.cos = np.zeros(n_channels), np.zeros(n_channels)
        self.sum, self.sumsq = np.zeros(n_channels), np.zeros(n_channels)
        self.ref: np.ndarray | None = None
        self.n_angvel, self.angvel_sq = 0, np.zeros(3)
        self._block = np.zeros((self.BLOCK, n_channels))
        self._pending = 0

    def add(self, scored: np.ndarray) -> None:
        """One frame's scored channels ``[C]`` (degrees)."""
        if self.ref is None:
            self.ref = scored.astype(np.float64)
        self._block[self._pending] = scored
        self._pending += 1
        if self._pending == self.BLOCK:
            self._fold()

    def _fold(self) -> None:
        """Add the pending frames to the sums."""
        block = self._block[: self._pending]
        rad = np.deg2rad(block)
        self.sin += np.sin(rad).sum(0)
        self.cos += np.cos(rad).sum(0)
        x = self.ref - ((self.ref - block + 180.0) % 360.0 - 180.0)
        self.sum += x.sum(0)
        self.sumsq += (x * x).sum(0)
        self.n += self._pending
        self._pending = 0

    def add_angvel(self, angvel: np.ndarray) -> None:
        """One frame's root angular velocity ``[3]`` (rad/s)."""
        self.angvel_sq += np.square(angvel, dtype=np.float64)
        self.n_angvel += 1

    def stats(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(center [C], scale [C], angvel_scale [3])`` as ``clip_statistics`` defines them."""
        if self._pending:
            self._fold()
        center = np.rad2deg(np.arctan2(self.sin, self.cos))
        mean = self.sum / max(self.n, 1)
        var = np.maximum(self.sumsq / max(self.n, 1) - mean * mean, 0.0)
        scale = np.maximum(np.sqrt(var), MIN_SCALE_DEG)
        angvel_scale = np.maximum(np.sqrt(self.angvel_sq / max(self.n_angvel, 1)), 1e-3)
        return center, scale, angvel_scale


def _stats_due(count: int, width: int) -> bool:
    """Whether a running-statistics stream refreshes at frame count ``count`` (``STATS_EVERY``)."""
    if count % STATS_EVERY == 0:
        return True
    ratio = count // width
    return count < STATS_EVERY and count % width == 0 and ratio & (ratio - 1) == 0


class EBFStream:
    """Frame-by-frame EBF cleaning with a fixed lookahead of ``half`` frames (windowed mode).

    ``push(frame)`` takes one frame of channels ``[C]`` (degrees, no gaps) and returns the frames that became
    final, as a list of ``(frame index, cleaned channels [C])``: from frame ``2·half`` on, one per call
    (frame ``t - half``; the first call that completes a window returns frames 0 … half). ``flush()`` returns
    the last ``half`` frames at the end of the stream. The steady state (one frame per call) runs
    ``_CentreKernel``; the first window and the flush run the torch modules.

    A ``norm="corpus"`` network gives exactly ``clean_channels(..., mode="windowed")`` on the whole clip. A
    ``norm="clip"`` network needs the clip's statistics: ``stats`` (``(center [C_s], scale [C_s],
    angvel_scale [3])``, e.g. ``clip_statistics`` of a calibration take) fixes them, and then the stream equals
    windowed mode given the same statistics; without them the stream uses those of what it has seen so far
    (``RunningStats``, refreshed on ``_stats_due`` frames; the flush refreshes them with every frame).
    """

    def __init__(
        self,
        model: EBF,
        skeleton: Skeleton,
        fps: float,
        stats: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> None:
        if not isinstance(model, EBF):
            raise TypeError("EBFStream streams EBF (and BF) models")
        check_skeleton(model, skeleton, fps=fps)
        self.model, self.skeleton, self.fps = model, skeleton, fps
        self.half = model.hparams.half
        self.width = 2 * self.half + 1
        self.idx = scored_index(skeleton)
        self.frames: deque[np.ndarray] = deque(maxlen=self.width)
        self.scored: deque[np.ndarray] = deque(maxlen=self.width)  # [C_s] float32
        self.angvel: deque[np.ndarray] = deque(maxlen=self.width)  # [3] rad/s
        self.count = 0
        # the kernel's inputs, frame k in slots k % W and k % W + W, so the last W frames are one slice
        self._ring_scored = np.zeros((2 * self.width, len(self.idx)), dtype=np.float32)
        self._ring_proj: np.ndarray | None = None  # [2W, 2, 1, 4H] layer-1 projections
        self._prev_rot: np.ndarray | None = None
        self._chain = context_chain(skeleton)
        self._kernel = _CentreKernel(model) if _CentreKernel.usable(model) else None
        if self._kernel is not None:
            self._ring_proj = np.zeros((2 * self.width, 2, 1, 4 * self._kernel.hidden), dtype=np.float32)
        clip_norm = model.hparams.get("norm", "corpus") == "clip"
        self.running = RunningStats(len(self.idx)) if clip_norm and stats is None else None
        fixed = (model.center.numpy(), model.scale.numpy(), model.angvel_scale.numpy())
        self._set_stats(stats if clip_norm and stats is not None else fixed)

    def _set_stats(self, stats: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Use ``(center, scale, angvel_scale)`` from now on (torch modules and kernel)."""
        self._stats = dict(zip(NORM_KEYS, (torch.as_tensor(s, dtype=torch.float32) for s in stats)))
        if self._kernel is not None:
            self._kernel.set_stats(*stats)

    def _refresh(self) -> None:
        """Take the running statistics and recompute the window's layer-1 projections with them."""
        self._set_stats(self.running.stats())
        if self._kernel is not None and len(self.angvel) == len(self.scored):
            proj = self._kernel.project(np.stack(self.scored), np.stack(self.angvel))
            for k, row in zip(range(self.count - len(proj), self.count), proj):
                self._store(self._ring_proj, k, row)

    def _store(self, ring: np.ndarray, frame: int, row: np.ndarray) -> None:
        """Write ``row`` as frame ``frame`` of a ring buffer ``[2W, ...]`` (slots ``frame % W`` and ``+ W``)."""
        slot = frame % self.width
        ring[slot] = row
        ring[slot + self.width] = row

    def _add_angvel(self, angvel: np.ndarray) -> None:
        """Record the angular velocity of the oldest frame without one (and its layer-1 projection for the
        kernel)."""
        frame = self.count - len(self.scored) + len(self.angvel) if len(self.angvel) < len(self.scored) else None
        self.angvel.append(angvel)
        if self.running is not None:
            self.running.add_angvel(angvel)
        if self._kernel is not None:
            frame = self.count - 1 if frame is None else frame
            scored = self._ring_scored[frame % self.width]
            self._store(self._ring_proj, frame, self._kernel.project(scored[None], angvel[None])[0])

    @torch.inference_mode()
    def _window(self) -> tuple[torch.Tensor, torch.Tensor]:
        """LSTM outputs ``[W, 2H]`` and scored channels ``[W, C]`` of the current window (torch modules)."""
        window = torch.as_tensor(np.stack(self.scored))
        angvel = torch.as_tensor(np.stack(self.angvel), dtype=torch.float32)
        codes = self.model.encoder(self.model.features(window[None], angvel[None], self._stats))
        return self.model.blstm.lstm(codes)[0][0], window

    def _frame_out(self, position: int, values: np.ndarray) -> tuple[int, np.ndarray]:
        """``(frame index, channels)`` of window ``position`` with its scored channels set to ``values``."""
        frame = self.frames[position].copy()
        frame[self.idx] = values
        return self.count - len(self.frames) + position, frame

    @torch.inference_mode()
    def _emit(self, positions: list[int]) -> list[tuple[int, np.ndarray]]:
        """Cleaned frames at ``positions`` of the current window, through the torch modules."""
        lstm_out, window = self._window()
        model, h = self.model, self.half
        params = model.head(lstm_out[positions])  # [n, P]
        weights = model.filter_weights(params[None])[0]  # [C, n, K]
        pos = torch.as_tensor(positions)
        taps = (pos[:, None] + torch.arange(-h, h + 1)).clamp(0, len(window) - 1)  # [n, K]
        filtered = (window[taps].permute(2, 0, 1) * weights).sum(-1).T  # [n, C]
        values = model.debias(filtered, params, self._stats["scale"])
        return [self._frame_out(p, v) for p, v in zip(positions, values.double().numpy())]

    def push(self, frame: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Add frame ``count`` (channels ``[C]``, degrees); return the frames that became final."""
        frame = np.asarray(frame, dtype=np.float64)
        rot = context_matrix(self._chain, frame)
        self.frames.append(frame)
        self.scored.append(frame[self.idx].astype(np.float32))
        self._store(self._ring_scored, self.count, self.scored[-1])
        if self.running is not None:
            self.running.add(frame[self.idx])
        self.count += 1
        if self._prev_rot is None:
            self._prev_rot = rot
            return []
        angvel = (relative_rotvec(self._prev_rot, rot) * self.fps).astype(np.float32)
        self._prev_rot = rot
        if self.count == 2:
            self._add_angvel(angvel)
        self._add_angvel(angvel)
        if self.running is not None and _stats_due(self.count, self.width):
            self._refresh()
        if self.count < self.width:
            return []
        if self.count == self.width:
            return self._emit(list(range(self.half + 1)))
        if self._kernel is None:
            return self._emit([self.half])
        start = self.count % self.width  # slot of frame count - W, the window's first
        end = start + self.width
        values = self._kernel.centre(self._ring_proj[start:end], self._ring_scored[start:end])
        return [self._frame_out(self.half, values.astype(np.float64))]

    def flush(self) -> list[tuple[int, np.ndarray]]:
        """End of stream: the frames not returned yet."""
        if self.count == 0:
            return []
        if self.count == 1:
            self.angvel.append(np.zeros(3, dtype=np.float32))
            if self.running is not None:
                self.running.add_angvel(self.angvel[0])
        if self.running is not None:
            self._refresh()
        if self.count < self.width:
            return self._emit(list(range(self.count)))
        return self._emit(list(range(self.half + 1, self.width)))
