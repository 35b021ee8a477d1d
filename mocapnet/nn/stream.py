"""Frame-by-frame EBF cleaning with a fixed lookahead (windowed mode, ``mocapnet.nn.infer``): ``EBFStream`` (and
``EBFStreams``, several streams in lockstep), the numpy kernel of its steady state (``_CentreKernel``; the ONNX
Runtime one is ``onnx_kernel``), the running input statistics of a ``norm="clip"`` or ``"both"`` network
(``RunningStats``) and the causal self-check (``RunningSelfCheck``).

The steady state costs one windowed-mode output per frame: 47 sequential LSTM steps (layer 1 over the 31-frame
window, both directions at once; layer 2 over the 16 steps its centre output depends on, both directions at
once). A step is one batched product and eight elementwise ufuncs on contiguous buffers, so Python's and numpy's
per-call overhead is most of the cost: the kernel keeps every step's operands in preallocated buffers laid out
so that each ufunc reads and writes one contiguous block.
"""

from __future__ import annotations

import numpy as np
import torch

from mocapnet.kinematics import wrap_deg, wrap_near
from mocapnet.motion import Skeleton
from mocapnet.nn import onnx_kernel
from mocapnet.nn.base import NORM_KEYS, input_features_numpy, uses_clip_statistics
from mocapnet.nn.ebf import EBF
from mocapnet.nn.features import (
    MIN_SCALE_DEG,
    context_chain,
    context_matrix,
    relative_rotvec,
    scored_index,
)
from mocapnet.nn.infer import check_skeleton
from mocapnet.nn.layers import dense_layers

#: Kernels of the steady state (``EBFStream``).
BACKENDS = ("auto", "numpy", "onnx")

#: torch's LSTM gate order is (i, f, g, o); the kernel's is (g, f, i, o): the cell input, then the three
#: sigmoid gates, so that one slice covers the sigmoid gates and ``[f | i]`` meets ``[c | g]`` in one product.
_TORCH_GATE = {"i": 0, "f": 1, "g": 2, "o": 3}
_KERNEL_GATES = "gfio"


class _CentreKernel:
    """EBF's windowed-mode output for the centre frame of full windows of ``B`` streams at once, in numpy float32
    (the streaming cleaner's steady state: one call per frame, so per-call overhead is what counts).

    Savings over running ``nn.LSTM`` on the window: layer 1's input projection is computed once per frame
    (``project``) and kept; both directions (and all streams) of a layer step together, in one batched product
    of the hidden state ``[2, B, H]`` (direction, stream, unit) with the recurrent weights ``[4, 2, H, H]``
    (gate, direction); the step buffer is laid out ``[c | g | f | i | o]``, each part ``[2, B, H]``, so every
    elementwise ufunc works on one contiguous block (strided views cost 2-3x as much per call); the weights of
    the three sigmoid gates are halved so one tanh covers all four gates (``σ(x) = (1 + tanh(x/2)) / 2``), and
    ``f·c`` and ``i·g`` are one product of adjacent pairs; layer 2 runs only the steps its centre output depends
    on (``half + 1`` each way instead of ``2·half + 1``); the encoder, head and filter touch one frame. Same
    arithmetic as the torch modules (float32 rounding apart). Not thread-safe: the step buffers are shared.
    """

    def __init__(self, model: EBF) -> None:
        lstm = model.blstm.lstm
        hid = self.hidden = lstm.hidden_size
        half_sig = np.array([1.0 if g == "g" else 0.5 for g in _KERNEL_GATES], dtype=np.float32)

        def gates(name: str, layer: int) -> np.ndarray:
            """``[4, 2, H, ...]``: a parameter of both directions, in kernel gate order, sigmoid rows halved."""
            both = [getattr(lstm, f"{name}_l{layer}{sfx}").detach().numpy() for sfx in ("", "_reverse")]
            w = np.stack(both).astype(np.float32).reshape(2, 4, hid, *both[0].shape[1:])
            w = w[:, [_TORCH_GATE[g] for g in _KERNEL_GATES]].swapaxes(0, 1)
            return w * half_sig.reshape((4,) + (1,) * (w.ndim - 1))

        # recurrent weights [4, 2, H, H] as right operands: gates[k, d] = h[d] @ whh[k, d]
        self.whh = [np.ascontiguousarray(gates("weight_hh", layer).swapaxes(2, 3)) for layer in (0, 1)]
        bias = [gates("bias_ih", layer) + gates("bias_hh", layer) for layer in (0, 1)]  # [4, 2, H]
        wih0 = gates("weight_ih", 0)  # [4, 2, H, F]
        self.wih0_t = np.ascontiguousarray(wih0.reshape(8 * hid, -1).T)  # [F, 8H], columns (gate, dir, unit)
        self.bias0 = bias[0].reshape(-1)
        wih1 = gates("weight_ih", 1)  # [4, 2, H, 2H]
        self.wih1_t = [np.ascontiguousarray(wih1[:, d].reshape(4 * hid, -1).T) for d in (0, 1)]  # [2H, 4H]
        self.bias1 = [np.ascontiguousarray(bias[1][:, d, None]) for d in (0, 1)]  # [4, 1, H]
        self.encoder = dense_layers(model.encoder)
        self.head = dense_layers(model.head)
        hp = model.hparams
        self.half, self.n_channels, self.n_filter = hp.half, hp.n_channels, model.n_filter
        self.free, self.has_bias = hp.filter_shape == "free", bool(hp.bias)
        self.bias_bound = float(hp.get("bias_bound", 3.0))
        self.corpus = _corpus_statistics(model) if hp.get("norm", "corpus") == "both" else None
        self.sincos = bool(hp.get("sincos", False))
        self.taps_sq = (np.arange(-self.half, self.half + 1, dtype=np.float32) ** 2)[None, None, :]
        self._half = np.array(0.5, dtype=np.float32)
        self._buffers: dict[int, dict] = {}

    @staticmethod
    def usable(model: EBF) -> bool:
        """Whether ``model``'s LSTM has the two layers this kernel computes."""
        return model.blstm.lstm.num_layers == 2 and model.blstm.stride == 1

    def _buffers_for(self, b: int) -> dict:
        """The step buffers for ``b`` streams (made on first use) and views of them made once: layer-1 step
        inputs ``[W, 4, 2, B, H]`` (step s: forward frame s, backward frame W-1-s) and outputs ``[W, 2, B, H]``,
        layer-2 step inputs ``[half+1, 4, 2, B, H]``, the step state ``[c | g | f | i | o]``."""
        if b in self._buffers:
            return self._buffers[b]
        hid, width, mid = self.hidden, 2 * self.half + 1, self.half
        n = 2 * b * hid
        buf = {
            "seq": np.zeros((width, 4, 2, b, hid), dtype=np.float32),
            "layer1": np.zeros((width, 2, b, hid), dtype=np.float32),
            "step2": np.zeros((mid + 1, 4, 2, b, hid), dtype=np.float32),
            "per_frame": np.zeros((width, b, 2 * hid), dtype=np.float32),  # layer-1 output per frame
            "proj2": np.zeros((mid + 1, b, 4 * hid), dtype=np.float32),
            "h": np.zeros((2, b, hid), dtype=np.float32),
            "tmp": np.zeros((2, b, hid), dtype=np.float32),
            "prod": np.zeros(2 * n, dtype=np.float32),
            "state": np.zeros(5 * n, dtype=np.float32),
        }
        z, prod = buf["state"], buf["prod"]
        buf |= {
            "seq_rows": [row.reshape(-1) for row in buf["seq"]],
            "layer1_rows": list(buf["layer1"]),
            "step2_rows": [row.reshape(-1) for row in buf["step2"]],
            "c": z[:n].reshape(2, b, hid),
            "o": z[4 * n :].reshape(2, b, hid),
            "gates": z[n:],
            "gates4": z[n:].reshape(4, 2, b, hid),
            "sig": z[2 * n :],
            "cg": z[: 2 * n],
            "fi": z[2 * n : 4 * n],
            "fc": prod[:n].reshape(2, b, hid),
            "ig": prod[n:].reshape(2, b, hid),
        }
        self._buffers[b] = buf
        return buf

    def project(
        self, scored: np.ndarray, angvel: np.ndarray, stats: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> np.ndarray:
        """Layer-1 LSTM input projections ``[N, 4, 2, H]`` (gate, direction; biases included) of frames with
        scored channels ``[N, C]`` (degrees) and root angular velocity ``[N, 3]`` (rad/s), normalised with
        ``stats`` = ``(center [C], scale [C], angvel_scale [3])`` (float32; beside the corpus buffers for
        ``norm="both"``)."""
        code = _run_dense(self.encoder, input_features_numpy(scored, angvel, stats, self.corpus, self.sincos))  # [N, F]
        out = code @ self.wih0_t
        out += self.bias0
        return out.reshape(len(out), 4, 2, self.hidden)

    def _steps(self, buf: dict, inputs: list[np.ndarray], outputs: list[np.ndarray] | None, whh: np.ndarray) -> None:
        """Run both directions of a layer from zero states over step inputs (views ``[8BH]``, layout (gate,
        direction, stream, unit)); the hidden states ``[2, B, H]`` go to ``outputs`` when given, else to
        ``buf["h"]``."""
        tanh, mul, add, matmul = np.tanh, np.multiply, np.add, np.matmul
        c, tmp, gates, gates4, sig, o = buf["c"], buf["tmp"], buf["gates"], buf["gates4"], buf["sig"], buf["o"]
        cg, fi, prod, fc, ig, half = buf["cg"], buf["fi"], buf["prod"], buf["fc"], buf["ig"], self._half
        h = buf["h"]
        h.fill(0.0)
        c.fill(0.0)
        for s, proj in enumerate(inputs):
            matmul(h, whh, out=gates4)
            add(gates, proj, out=gates)
            tanh(gates, out=gates)  # sigmoid gates: tanh of half their input (weights halved)
            mul(sig, half, out=sig)
            add(sig, half, out=sig)
            mul(fi, cg, out=prod)  # [f·c | i·g]
            add(fc, ig, out=c)
            tanh(c, out=tmp)
            h = buf["h"] if outputs is None else outputs[s]
            mul(o, tmp, out=h)

    def centre(self, proj: np.ndarray, window: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
        """Cleaned scored channels ``[B, C]`` of the centre frames, from each stream's window of layer-1
        projections ``[B, W, 4, 2, H]`` (``W = 2·half + 1``) and scored channels ``[B, W, C]`` (degrees);
        ``scale`` ``[B, C]`` or ``[C]`` (degrees) is the unit of the bias (bias networks only)."""
        b, mid, hid = len(proj), self.half, self.hidden
        buf = self._buffers_for(b)
        seq, layer1, per_frame, step2, proj2 = buf["seq"], buf["layer1"], buf["per_frame"], buf["step2"], buf["proj2"]
        seq[:, :, 0] = proj[:, :, :, 0].transpose(1, 2, 0, 3)
        seq[:, :, 1] = proj[:, ::-1, :, 1].transpose(1, 2, 0, 3)
        self._steps(buf, buf["seq_rows"], buf["layer1_rows"], self.whh[0])
        per_frame[..., :hid] = layer1[:, 0]
        per_frame[..., hid:] = layer1[::-1, 1]
        # layer 2, forward: frames 0 … mid; backward: frames W-1 … mid (products on positive strides: numpy
        # multiplies a reversed view without BLAS)
        for d, frames in enumerate((per_frame[: mid + 1], per_frame[mid:])):
            np.matmul(frames, self.wih1_t[d], out=proj2)
            p = proj2.reshape(mid + 1, b, 4, hid).transpose(0, 2, 1, 3)
            np.add(p[::-1] if d else p, self.bias1[d], out=step2[:, :, d])
        self._steps(buf, buf["step2_rows"], None, self.whh[1])
        params = _run_dense(self.head, buf["h"].transpose(1, 0, 2).reshape(b, -1))  # [B, P]
        raw = params[:, : self.n_filter]
        if self.free:
            logits = raw.reshape(b, self.n_channels, -1)
        else:
            logits = -0.5 * self.taps_sq * np.exp(-2.0 * np.clip(raw, -5.0, 5.0))[..., None]
        weights = np.exp(logits - logits.max(axis=2, keepdims=True))  # [B, C, K]
        values = np.einsum("bck,bkc->bc", weights, window) / weights.sum(axis=2)
        if self.has_bias:
            bound = self.bias_bound
            values = values - scale * bound * np.tanh(params[:, self.n_filter :] / bound)
        return values


def _corpus_statistics(model: EBF) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``model``'s corpus buffers as numpy ``(center [C], scale [C], angvel_scale [3])`` (float32)."""
    return tuple(getattr(model, key).numpy() for key in NORM_KEYS)


def _run_dense(layers: list[tuple[np.ndarray, np.ndarray, bool]], x: np.ndarray) -> np.ndarray:
    """Rows ``x [N, F]`` through the dense layers of ``layers.dense_layers``."""
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
        x = wrap_near(block, self.ref)
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


class RunningSelfCheck:
    """EBF's self-check (``selfcheck.limit_change``) applied causally: each scored channel's change is capped at
    ``factor`` × the white-noise σ its input shows, both known from the frames seen so far. σ is
    ``selfcheck.noise_level``'s estimate (MAD of second differences) over the last ``HISTORY`` frames, refreshed
    on the running statistics' schedule (``_stats_due``) and at the flush; the RMS change is that of every
    frame returned so far, the frames being returned included; frames returned together (the first window, the
    flush) share one cap. A stream shorter than one window thus gets exactly ``limit_change`` of windowed
    mode; on a longer one the early frames see estimates from fewer frames."""

    HISTORY = 4096

    def __init__(self, n_channels: int, factor: float) -> None:
        self.factor = factor
        self.sigma = np.zeros(n_channels)
        self._cap = np.zeros(n_channels)
        self._prev: np.ndarray | None = None
        self._d1: np.ndarray | None = None
        self._d2 = np.zeros((self.HISTORY, n_channels))
        self._n_d2 = 0
        self._sumsq, self._n_out = np.zeros(n_channels), 0

    def add(self, scored: np.ndarray) -> None:
        """One input frame's scored channels ``[C]`` (degrees): its second difference joins the history."""
        if self._prev is not None:
            d1 = wrap_deg(scored - self._prev)  # the first difference of the unwrapped series
            if self._d1 is not None:
                self._d2[self._n_d2 % self.HISTORY] = d1 - self._d1
                self._n_d2 += 1
            self._d1 = d1
        self._prev = scored

    def refresh(self) -> None:
        """Re-estimate σ ``[C]`` from the history (``selfcheck.noise_level``'s formula; zeros before 3 frames)."""
        d2 = self._d2[: min(self._n_d2, self.HISTORY)]
        if len(d2):
            dev = np.abs(d2 - np.median(d2, axis=0))
            self.sigma = 1.4826 * np.median(dev, axis=0) / np.sqrt(6.0)
            self._cap = self.factor * self.sigma

    def apply(self, noisy: np.ndarray, cleaned: np.ndarray) -> np.ndarray:
        """``cleaned [n, C]`` moved toward ``noisy [n, C]`` (degrees) as ``limit_change`` would, with the running
        RMS change (these ``n`` frames included) and the current σ."""
        change = wrap_deg(cleaned - noisy)
        self._sumsq += np.square(change).sum(axis=0)
        self._n_out += len(change)
        rms = np.sqrt(self._sumsq / self._n_out)
        change *= np.minimum(self._cap / np.maximum(rms, 1e-12), 1.0)  # 1 where rms ≤ cap
        return noisy + change


class _Ring:
    """The last ``width`` rows ``[*shape]`` of a stream: frame k sits in slots ``k % W`` and ``k % W + W``, so
    any ``n ≤ W`` consecutive frames are one slice (``last``)."""

    def __init__(self, width: int, shape: tuple[int, ...], dtype: type) -> None:
        self.width = width
        self.data = np.zeros((2 * width, *shape), dtype=dtype)

    def store(self, frame: int, row: np.ndarray) -> None:
        """Write ``row`` as frame ``frame``."""
        slot = frame % self.width
        self.data[slot] = row
        self.data[slot + self.width] = row

    def last(self, first: int, n: int) -> np.ndarray:
        """Frames ``first … first + n - 1`` (the latest ``n`` stored, ``n ≤ W``) as a view ``[n, *shape]``."""
        start = first % self.width
        return self.data[start : start + n]


class EBFStream:
    """Frame-by-frame EBF cleaning with a fixed lookahead of ``half`` frames (windowed mode).

    ``push(frame)`` takes one frame of channels ``[C]`` (degrees, no gaps) and returns the frames that became
    final, as a list of ``(frame index, cleaned channels [C])``: from frame ``2·half`` on, one per call
    (frame ``t - half``; the first call that completes a window returns frames 0 … half). ``flush()`` returns
    the last ``half`` frames at the end of the stream. The steady state (one frame per call) runs a kernel:
    ``backend="onnx"`` the whole step as one ONNX Runtime graph (``onnx_kernel``; optional dependencies, about
    half the CPU time), ``"numpy"`` ``_CentreKernel``, ``"auto"`` (default) ONNX Runtime when it is installed;
    the first window and the flush run the torch modules. ``EBFStreams`` runs several streams in lockstep
    through one (numpy) kernel call per frame.

    ``change_limit``: the self-check factor (None: the checkpoint's ``change_limit``; 0: none), applied causally
    (``RunningSelfCheck``). Without it (or on a stream shorter than one window) a ``norm="corpus"`` network
    gives exactly ``clean_channels(..., mode="windowed")`` on the whole clip. A
    ``norm="clip"`` network needs the clip's statistics, and so does a ``norm="both"`` one for its
    clip-normalised inputs (its corpus-normalised ones beside them use the model's buffers, as offline): ``stats``
    (``(center [C_s], scale [C_s], angvel_scale [3])``, e.g. ``clip_statistics`` of a calibration take; also the
    unit of the bias, as offline) fixes them, and then the stream equals
    windowed mode given the same statistics; without them the stream uses those of what it has seen so far
    (``RunningStats``, refreshed on ``_stats_due`` frames; the flush refreshes them with every frame; the ONNX
    kernel normalises the whole window with the current statistics at every frame, the numpy kernel keeps each
    frame's layer-1 input from the statistics it arrived under until a refresh recomputes the window's).
    """

    def __init__(
        self,
        model: EBF,
        skeleton: Skeleton,
        fps: float,
        stats: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        backend: str = "auto",
        change_limit: float | None = None,
    ) -> None:
        if not isinstance(model, EBF):
            raise TypeError("EBFStream streams EBF (and BF) models")
        if model.hparams.get("deltas", "off") != "off":
            raise ValueError("EBFStream cannot stream a network with delta inputs (deltas != 'off'): clean offline")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if backend == "onnx" and not onnx_kernel.available():
            raise ValueError("backend='onnx' needs the optional packages onnx and onnxruntime (mocapnet[onnx])")
        check_skeleton(model, skeleton, fps=fps)
        self.model, self.skeleton, self.fps = model, skeleton, fps
        self.half = model.hparams.half
        self.width = width = 2 * self.half + 1
        self.idx = scored_index(skeleton)
        self.n_columns = skeleton.n_channels
        self.count = 0
        # the last W frames: all channels, the scored ones (float32), root angular velocity (rad/s, float32;
        # frame 0's is known one frame late, when frame 1 arrives) and the kernel's layer-1 projections
        self._frames = _Ring(width, (self.n_columns,), np.float64)
        self._scored = _Ring(width, (len(self.idx),), np.float32)
        self._angvel = _Ring(width, (3,), np.float32)
        self._prev_rot: np.ndarray | None = None
        self._chain = context_chain(skeleton)
        usable = _CentreKernel.usable(model)
        use_onnx = usable and (backend == "onnx" or (backend == "auto" and onnx_kernel.available()))
        self._onnx = None
        if use_onnx:
            try:
                self._onnx = onnx_kernel.OnnxKernel(model)
            except (ImportError, OSError):  # installed but unusable (e.g. a missing shared library)
                if backend == "onnx":
                    raise
                use_onnx = False
        self._kernel = _CentreKernel(model) if usable and not use_onnx else None
        if self._kernel is not None:
            self._proj = _Ring(width, (4, 2, self._kernel.hidden), np.float32)
        clip_norm = uses_clip_statistics(model)
        self.running = RunningStats(len(self.idx)) if clip_norm and stats is None else None
        self._set_stats(stats if clip_norm and stats is not None else _corpus_statistics(model))
        limit = float(model.hparams.get("change_limit", 0.0)) if change_limit is None else change_limit
        if limit < 0:
            raise ValueError(f"change_limit must be >= 0, got {limit}")
        self.check = RunningSelfCheck(len(self.idx), limit) if limit > 0 else None

    def _set_stats(self, stats: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Normalise with ``(center, scale, angvel_scale)`` from now on (torch modules and kernel)."""
        self._norm = tuple(np.asarray(s, dtype=np.float32) for s in stats)
        self._stats = dict(zip(NORM_KEYS, (torch.as_tensor(s) for s in self._norm)))

    def _window_start(self) -> tuple[int, int]:
        """``(first frame, frames)`` of the current window: the latest ``min(count, W)`` frames."""
        n = min(self.count, self.width)
        return self.count - n, n

    def _refresh(self) -> None:
        """Take the running statistics and recompute the window's layer-1 projections with them."""
        self._set_stats(self.running.stats())
        if self._kernel is not None and self.count > 1:
            first, n = self._window_start()
            proj = self._kernel.project(self._scored.last(first, n), self._angvel.last(first, n), self._norm)
            for frame, row in enumerate(proj, start=first):
                self._proj.store(frame, row)

    def _set_angvel(self, frame: int, angvel: np.ndarray) -> None:
        """Record the root angular velocity ``[3]`` of ``frame`` (and its layer-1 projection for the kernel)."""
        self._angvel.store(frame, angvel)
        if self.running is not None:
            self.running.add_angvel(angvel)
        if self._kernel is not None:
            scored = self._scored.data[frame % self.width]
            self._proj.store(frame, self._kernel.project(scored[None], angvel[None], self._norm)[0])

    @torch.inference_mode()
    def _window(self) -> tuple[torch.Tensor, torch.Tensor]:
        """LSTM outputs ``[n, 2H]`` and scored channels ``[n, C]`` of the current window (torch modules)."""
        first, n = self._window_start()
        window = torch.as_tensor(self._scored.last(first, n).copy())
        angvel = torch.as_tensor(self._angvel.last(first, n).copy())
        codes = self.model.encoder(self.model.features(window[None], angvel[None], self._stats))
        return self.model.blstm.lstm(codes)[0][0], window

    def _finish(self, positions: list[int], values: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """``(frame index, channels)`` of each window position with its scored channels set to ``values [n, C]``
        (after the self-check)."""
        first = self._window_start()[0]
        frames = [self._frames.data[(first + p) % self.width].copy() for p in positions]
        if self.check is not None:
            values = self.check.apply(np.stack([f[self.idx] for f in frames]), values)
        for frame, v in zip(frames, values):
            frame[self.idx] = v
        return list(zip((first + p for p in positions), frames))

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
        return self._finish(positions, values.double().numpy())

    def _advance(self, frame: np.ndarray) -> list[tuple[int, np.ndarray]] | None:
        """Everything of ``push`` but the kernel: the frames that became final, or None when the centre frame
        of the window now full is due from the kernel."""
        frame = np.asarray(frame, dtype=np.float64)
        if frame.shape != (self.n_columns,) or not np.isfinite(frame).all():
            raise ValueError(
                f"frame {self.count}: expected {self.n_columns} finite channels, got shape {frame.shape}"
                + ("" if frame.shape != (self.n_columns,) else " with NaN or infinite values")
            )
        k = self.count
        rot = context_matrix(self._chain, frame)
        self._frames.store(k, frame)
        self._scored.store(k, frame[self.idx])
        if self.running is not None:
            self.running.add(frame[self.idx])
        if self.check is not None:
            self.check.add(frame[self.idx])
        self.count += 1
        if self._prev_rot is None:
            self._prev_rot = rot
            return []
        angvel = (relative_rotvec(self._prev_rot, rot) * self.fps).astype(np.float32)
        self._prev_rot = rot
        if k == 1:
            self._set_angvel(0, angvel)  # frame 0 repeats frame 1's, as root_angular_velocity does
        self._set_angvel(k, angvel)
        if _stats_due(self.count, self.width):
            if self.running is not None:
                self._refresh()
            if self.check is not None:
                self.check.refresh()
        if self.count < self.width:
            return []
        if self.count == self.width:
            return self._emit(list(range(self.half + 1)))
        if self._kernel is None and self._onnx is None:
            return self._emit([self.half])
        return None

    def _kernel_inputs(self) -> tuple[np.ndarray, np.ndarray]:
        """The current (full) window's layer-1 projections ``[W, 4, 2, H]`` and scored channels ``[W, C]``."""
        first = self.count - self.width
        return self._proj.last(first, self.width), self._scored.last(first, self.width)

    def push(self, frame: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Add frame ``count`` (channels ``[C]``, degrees); return the frames that became final. ValueError
        naming the frame when it does not hold the skeleton's ``C`` finite channels."""
        done = self._advance(frame)
        if done is not None:
            return done
        if self._onnx is not None:
            first = self.count - self.width
            window, angvel = self._scored.last(first, self.width), self._angvel.last(first, self.width)
            values = self._onnx.centre(window, angvel, self._norm)
        else:
            proj, window = self._kernel_inputs()
            values = self._kernel.centre(proj[None], window[None], self._norm[1])[0]
        return self._finish([self.half], values[None].astype(np.float64))

    def flush(self) -> list[tuple[int, np.ndarray]]:
        """End of stream: the frames not returned yet."""
        if self.count == 0:
            return []
        if self.count == 1:
            zero = np.zeros(3, dtype=np.float32)
            self._angvel.store(0, zero)
            if self.running is not None:
                self.running.add_angvel(zero)
        if self.running is not None:
            self._refresh()
        if self.check is not None:
            self.check.refresh()
        if self.count < self.width:
            return self._emit(list(range(self.count)))
        return self._emit(list(range(self.half + 1, self.width)))


class EBFStreams:
    """``n`` ``EBFStream`` s of one network and skeleton pushed in lockstep (e.g. several performers or
    takes at once): ``push(frames [n, C])`` returns each stream's list of final frames; the centre frames of
    all streams come from one kernel call, whose batched products cost much less per stream than ``n`` single
    calls. ``stats``: as for ``EBFStream``, one tuple for every stream or a list of ``n``; ``change_limit`` as for
    ``EBFStream``. Outputs are those of
    ``n`` separate ``EBFStream`` s (float32 rounding apart)."""

    def __init__(
        self,
        model: EBF,
        skeleton: Skeleton,
        fps: float,
        n: int,
        stats: tuple | list | None = None,
        change_limit: float | None = None,
    ) -> None:
        if n < 1:
            raise ValueError(f"EBFStreams needs at least one stream, got n={n}")
        per_stream = stats if isinstance(stats, list) else [stats] * n
        if len(per_stream) != n:
            raise ValueError(f"EBFStreams: {len(per_stream)} statistics for {n} streams")
        self.streams = [EBFStream(model, skeleton, fps, s, "numpy", change_limit) for s in per_stream]
        self._kernel = self.streams[0]._kernel
        for stream in self.streams[1:]:  # one kernel: its weights once, its buffers sized for n
            stream._kernel = self._kernel
        self.half, self.width = self.streams[0].half, self.streams[0].width

    def push(self, frames: np.ndarray) -> list[list[tuple[int, np.ndarray]]]:
        """Add one frame ``[C]`` to each stream (``frames [n, C]``, degrees); return each stream's final frames."""
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim != 2 or len(frames) != len(self.streams):
            raise ValueError(f"EBFStreams.push: expected frames [{len(self.streams)}, C], got shape {frames.shape}")
        done = [stream._advance(frame) for stream, frame in zip(self.streams, frames)]
        due = [i for i, d in enumerate(done) if d is None]
        if due:
            inputs = [self.streams[i]._kernel_inputs() for i in due]
            scale = np.stack([self.streams[i]._norm[1] for i in due])
            values = self._kernel.centre(np.stack([p for p, _ in inputs]), np.stack([w for _, w in inputs]), scale)
            for i, v in zip(due, values.astype(np.float64)):
                done[i] = self.streams[i]._finish([self.half], v[None])
        return done

    def flush(self) -> list[list[tuple[int, np.ndarray]]]:
        """End of the streams: each stream's frames not returned yet."""
        return [stream.flush() for stream in self.streams]
