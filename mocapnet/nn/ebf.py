"""EBF (Encoder-Bidirectional-Filter): predicts, for every scored channel at every frame, a smoothing filter
over the ``2·half+1`` frames around it and applies it to the noisy input (EBF paper, Sec. 3).

Per frame the input is the normalised scored channels plus the root angular velocity; an encoder of
``encoder_layers`` tanh layers maps it to a ``code``-D vector (``encoder_layers=0`` gives the BF ablation:
no encoder); two bidirectional LSTM layers (``hidden`` units per direction, dropout on their inputs) follow;
a filter head of ``head_layers`` tanh layers ends in the filter parameters:

* ``filter_shape="gaussian"``: one ``log σ`` per channel (σ in frames, ``exp`` keeps it positive); taps are the
  normalised Gaussian ``w(k) ∝ exp(-k²/2σ²)``, ``k = -half … half``;
* ``filter_shape="free"``: ``2·half+1`` logits per channel, softmax over taps;
* ``bias=True`` adds one bias per channel (non-zero-mean noise): ``x̂(t) = Σ_k w(k) x(t+k) − b(t)``, with
  ``b`` bounded to ±``bias_bound`` channel scales (``bias_bound·tanh(raw/bias_bound)``; default 3).

``norm="corpus"`` (default) normalises the inputs with the training set's statistics; ``norm="clip"`` with
each clip's own (``base.clip_statistics`` of the noisy input), and then the bias is in units of that clip's
scale too, so the network sees the same relative noise on a clip of any corpus; ``norm="both"`` gives it both
inputs side by side (``base.input_features``; a stream takes the running clip statistics for the clip part).
``sincos=True`` adds the sine and cosine of every scored channel to the inputs (``base.input_features``);
``deltas="add"`` each channel's first and second differences, ``deltas="only"`` those instead of the angles
(``base.frame_deltas``; offline only).
``change_limit`` is used at inference only: the self-check factor of ``selfcheck.limit_change`` (0: off), chosen on
the validation fold and stored with the checkpoint.

Departures from the paper, all configurable: hidden size 64 per direction by default (the paper used about
one unit per channel: 126 for 126 channels; bandai2 has 60 scored channels, CMU 90); PyTorch's default weight
initialisation (the paper's uniform [-0.5, 0.5] saturates 128-wide tanh layers) with the σ head starting at
``sigma_init`` frames everywhere; inputs wrapped into ``center ± 180°`` before normalising (see
``features.Normaliser``); training (``mocapnet.nn.train``) uses Adam with the learning rate halved when the
validation error stalls, and gradient clipping.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from mocapnet.adaptive_smooth import kernel_radius
from mocapnet.nn.base import DELTAS, NORMS, CleanerModule, n_inputs
from mocapnet.nn.layers import (
    BLSTM,
    gaussian_filter,
    gaussian_weights,
    init_log_sigma_bias,
    mlp,
    softmax_filter,
    tapered,
)

#: Training losses of the EBF (``EBF.loss_terms``): every sample's squared error alike (``"samples"``), or each
#: crop's divided by that of a Gaussian of ``RATIO_REFERENCE_S`` on the same noisy crop plus ``RATIO_FLOOR_DEG``²
#: (``"gaussian_ratio"``: the squared ratio the benchmark reports, per crop, so heavy noise does not outweigh light).
EBF_LOSSES = ("samples", "gaussian_ratio")
#: The reference Gaussian's standard deviation (s): the protocol's gaussian-58ms.
RATIO_REFERENCE_S = 0.058
#: Degrees added (squared) to the reference's mean squared error, so a crop the Gaussian fits almost exactly is
#: not weighted without bound.
RATIO_FLOOR_DEG = 0.1


class EBF(CleanerModule):
    """Encoder-Bidirectional-Filter denoiser for ``n_channels`` scored channels (degrees).

    Metadata kept in the hyper-parameters (checked by the adapters, not used by the network):
    ``skeleton_hash`` (``features.topology_hash``), ``fps``, ``corpus``.
    """

    def __init__(
        self,
        n_channels: int,
        hidden: int = 64,
        code: int = 64,
        width: int = 128,
        encoder_layers: int = 4,
        head_layers: int = 4,
        dropout: float = 0.5,
        half: int = 15,
        filter_shape: str = "gaussian",
        bias: bool = False,
        sigma_init: float = 2.0,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        lr_patience: int = 4,
        lr_schedule: str = "plateau",
        norm: str = "corpus",
        sincos: bool = False,
        deltas: str = "off",
        bias_bound: float = 3.0,
        change_limit: float = 0.0,
        skeleton_hash: str = "",
        fps: float = 0.0,
        corpus: str = "",
        loss: str = "samples",
    ) -> None:
        super().__init__(n_channels, lr, weight_decay, lr_patience)
        if loss not in EBF_LOSSES:
            raise ValueError(f"loss must be one of {EBF_LOSSES}, got {loss!r}")
        if loss == "gaussian_ratio" and not fps > 0:
            raise ValueError(f"loss='gaussian_ratio' needs the frame rate (fps > 0), got fps={fps!r}")
        if filter_shape not in ("gaussian", "free"):
            raise ValueError(f"filter_shape must be 'gaussian' or 'free', got {filter_shape!r}")
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        if deltas not in DELTAS:
            raise ValueError(f"deltas must be one of {DELTAS}, got {deltas!r}")
        if deltas == "only" and (norm == "both" or sincos):
            raise ValueError("deltas='only' is pose-free; it cannot go with norm='both' or sincos (both feed angles)")
        if not change_limit >= 0:
            raise ValueError(f"change_limit must be >= 0, got {change_limit!r}")
        if not bias_bound > 0:
            raise ValueError(f"bias_bound must be positive, got {bias_bound!r}")
        self.save_hyperparameters()
        n_in = n_inputs(n_channels, norm, sincos, deltas)
        encoder = mlp(tapered(n_in, code, encoder_layers), last_activation=True) if encoder_layers else None
        self.encoder = encoder or nn.Identity()
        self.blstm = BLSTM(code if encoder_layers else n_in, hidden, layers=2, dropout=dropout)
        self.n_filter = n_channels * (2 * half + 1) if filter_shape == "free" else n_channels
        n_out = self.n_filter + (n_channels if bias else 0)
        self.head = mlp([2 * hidden] + [width] * (head_layers - 1) + [n_out], last_activation=False)
        last = self.head[-1]
        if filter_shape == "gaussian":
            init_log_sigma_bias(last, sigma_init)
        else:
            nn.init.uniform_(last.weight, -1e-3, 1e-3)
            k = torch.arange(-half, half + 1, dtype=torch.float32)
            with torch.no_grad():
                last.bias[: self.n_filter] = (-0.5 * k**2 / sigma_init**2).repeat(n_channels)
        if bias:
            with torch.no_grad():
                last.bias[self.n_filter :] = 0.0

    def features(
        self, filled: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """``[B, T, C]`` degrees and ``[B, T, 3]`` rad/s → encoder input ``[B, T, n_inputs(C, norm, sincos, deltas)]``
        (``input_features``), normalised with ``stats`` (from ``input_stats``; default
        ``input_stats(filled, angvel)``)."""
        stats = self.input_stats(filled, angvel) if stats is None else stats
        return self.input_features(filled, angvel, stats)

    def filter_weights(self, params: torch.Tensor) -> torch.Tensor:
        """Head output ``[B, T, P]`` → tap weights ``[B, C, T, K]`` (each row sums to 1)."""
        b, t, _ = params.shape
        c, k = self.hparams.n_channels, 2 * self.hparams.half + 1
        raw = params[..., : self.n_filter]
        if self.hparams.filter_shape == "gaussian":
            return gaussian_weights(raw.clamp(-5.0, 5.0).transpose(1, 2), self.hparams.half)
        return torch.softmax(raw.reshape(b, t, c, k).permute(0, 2, 1, 3), dim=-1)

    def sigma(self, params: torch.Tensor) -> torch.Tensor:
        """Gaussian σ ``[B, T, C]`` in frames (gaussian filter only)."""
        return params[..., : self.n_filter].clamp(-5.0, 5.0).exp()

    def apply_hidden(self, filled: torch.Tensor, hidden: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        """Filter ``filled [B, T, C]`` with the head output computed from ``hidden [B, T, W]``, the input of the
        head's last layer → ``[B, T, C]`` degrees, tap by tap (``layers.gaussian_filter`` / ``softmax_filter``:
        the filtered samples ``[B, C, T, K]`` are never formed); ``scale`` (``[C]`` or ``[B, 1, C]`` degrees) is
        the unit of the bias (``debias``). A free kernel's logits come out tap-major (the layer's rows
        permuted), so each tap's ``[B, T, C]`` logits are contiguous: reading every K-th value of the
        channel-major output, tap after tap, was most of the offline time."""
        last = self.head[-1]
        half, n_filter = self.hparams.half, self.n_filter
        if self.hparams.filter_shape == "gaussian":
            params = last(hidden)
            return self.debias(gaussian_filter(filled, params[..., :n_filter].clamp(-5.0, 5.0), half), params, scale)
        k = 2 * half + 1
        order = torch.arange(n_filter, device=hidden.device).view(-1, k).T.reshape(-1)  # tap-major → head row
        order = torch.cat([order, torch.arange(n_filter, last.out_features, device=hidden.device)])
        params = nn.functional.linear(hidden, last.weight[order], last.bias[order])
        logits = params[..., :n_filter].unflatten(-1, (k, -1))  # [B, T, K, C]
        filtered = softmax_filter(filled, lambda tap: logits[..., tap + half, :], half, logits.amax(-2))
        return self.debias(filtered, params, scale)

    def debias(self, filtered: torch.Tensor, params: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        """Subtract the predicted bias (``bias=True``; else identity): ``filtered [..., C]`` degrees, head output
        ``params [..., P]``; the bias is ``bias_bound·tanh(raw/bias_bound)`` times ``scale`` (degrees)."""
        if not self.hparams.bias:
            return filtered
        bound = float(self.hparams.get("bias_bound", 3.0))
        return filtered - scale * bound * torch.tanh(params[..., self.n_filter :] / bound)

    def filter_params(
        self, filled: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """Sequence mode: head output ``[B, T, P]`` for whole clips ``[B, T, C]``, ``[B, T, 3]`` (``stats`` as in
        ``features``)."""
        return self.head(self.blstm(self.encoder(self.features(filled, angvel, stats))))

    def forward(
        self, filled: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """Sequence mode: cleaned channels ``[B, T, C]`` (degrees) from noisy ``[B, T, C]`` and ``[B, T, 3]``;
        ``stats`` (``NORM_KEYS``, ``[B, 1, ·]``) are the clips' statistics for ``norm="clip"`` (default:
        computed over the given frames)."""
        stats = self.input_stats(filled, angvel, stats)
        hidden = self.head[:-1](self.blstm(self.encoder(self.features(filled, angvel, stats))))
        return self.apply_hidden(filled, hidden, stats["scale"])

    def predict_batch(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self(batch["filled"], batch["angvel"], batch if "scale" in batch else None)

    @property
    def loss_in_degrees(self) -> bool:
        return self.hparams.get("loss", "samples") == "samples"

    def loss_terms(self, batch: dict[str, torch.Tensor], pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Squared errors (degrees², ``loss="samples"``) over every sample; ``"gaussian_ratio"``: each crop's
        divided by the mean squared error of a Gaussian of ``RATIO_REFERENCE_S`` (at the model's ``fps``) on the
        same noisy crop (``batch["filled"]``) plus ``RATIO_FLOOR_DEG``² (``[B, 1, 1]``, no gradient)."""
        sq, sel = super().loss_terms(batch, pred)
        if self.hparams.get("loss", "samples") == "samples":
            return sq, sel
        with torch.no_grad():
            filled, clean = batch["filled"], batch["clean"]
            sigma = RATIO_REFERENCE_S * self.hparams.fps  # frames; the kernel cut where gaussian-58ms's is
            log_sigma = filled.new_full(filled.shape, float(np.log(sigma)))
            ref = (gaussian_filter(filled, log_sigma, kernel_radius(sigma)) - clean) ** 2
            weight = sel.to(ref.dtype)
            ref_mse = (ref * weight).sum((1, 2), keepdim=True) / weight.sum((1, 2), keepdim=True).clamp(min=1.0)
        return sq / (ref_mse + RATIO_FLOOR_DEG**2), sel

    def predict_chunked(
        self, batch: dict[str, torch.Tensor], starts: np.ndarray, cores: np.ndarray, width: int, per_group: int
    ) -> torch.Tensor:
        """Sequence mode on a long clip, a batch of 1 (``infer.predict_sequence``): output ``[T, C]`` equal to
        running ``predict_batch`` on each window ``[starts_i, starts_i + width)`` and keeping its core
        ``[cores_i, cores_{i+1})``, with only the LSTM run on the windows. ``per_group`` windows at a time: the
        encoder runs once per frame of the span they cover, the head once per kept frame (its filter needs only
        the ``half`` input frames beyond the group's cores); memory is O(T·C) for the output and O(group)
        for the rest. A network with delta inputs (``deltas``) differs slightly: its inputs at a window's edges
        see the frame beyond (the span's), where ``predict_batch`` on the window alone counts a zero step."""
        # frame-major memory: the filter's per-tap sums run several times slower on a transposed input
        filled, angvel = batch["filled"].contiguous(), batch["angvel"].contiguous()
        n, half = filled.shape[1], self.hparams.half
        stats = self.input_stats(filled, angvel, batch if "scale" in batch else None)
        out = filled.new_empty(n, filled.shape[2])
        frames, chunk = torch.arange(width), int(cores[1] - cores[0]) if len(cores) > 1 else n
        for g in range(0, len(starts), per_group):
            ws, cs = starts[g : g + per_group], cores[g : g + per_group]
            span = slice(int(ws[0]), int(ws[-1]) + width)  # the frames the group's windows cover
            codes = self.encoder(self.features(filled[:, span], angvel[:, span], stats))[0]  # [span, F]
            lstm = self.blstm(codes[torch.as_tensor(ws - span.start)[:, None] + frames])  # [G, W, 2H]
            first, last = int(cs[0]), min(int(cs[-1]) + chunk, n)
            lo, hi = max(first - half, 0), min(last + half, n)  # the filter's input frames
            hidden = lstm.new_zeros(hi - lo, lstm.shape[2])  # frames outside the cores are cut off below
            for i, (w0, c0) in enumerate(zip(ws, cs)):
                c1 = min(int(c0) + chunk, n)
                hidden[c0 - lo : c1 - lo] = lstm[i, c0 - w0 : c1 - w0]
            pred = self.apply_hidden(filled[:, lo:hi], self.head[:-1](hidden)[None], stats["scale"])
            out[first:last] = pred[0, first - lo : last - lo]
        return out

    def windowed(
        self,
        filled: torch.Tensor,
        mask: torch.Tensor,
        angvel: torch.Tensor,
        stats: dict[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Windowed mode (``CleanerModule.windowed``); ``norm="clip"`` statistics are those of the whole clip
        (``stats`` ``[1, ·]`` when given)."""
        stats = self.input_stats(filled, angvel, stats)
        codes = self.encoder(self.features(filled, angvel, stats))
        hidden = self.head[:-1](self.blstm.windowed(codes, self.hparams.half))
        return self.apply_hidden(filled[None], hidden[None], stats["scale"])[0]
