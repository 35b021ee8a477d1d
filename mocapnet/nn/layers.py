"""Building blocks shared by the networks: tanh MLPs (encoder, filter head, decoder), a bidirectional LSTM
that runs in sequence or windowed mode, and the per-channel 31-tap filter.

Shapes: ``B`` batch, ``T`` frames, ``C`` scored channels, ``F`` features, ``K`` filter taps (``2·half+1``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import nn


def mlp(sizes: list[int], last_activation: bool) -> nn.Sequential:
    """Fully connected layers ``sizes[0] → … → sizes[-1]`` with tanh between them (and after the last one
    when ``last_activation``)."""
    layers: list[nn.Module] = []
    for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(n_in, n_out))
        if last_activation or i < len(sizes) - 2:
            layers.append(nn.Tanh())
    return nn.Sequential(*layers)


def tapered(n_in: int, n_out: int, n_layers: int) -> list[int]:
    """Layer widths from ``n_in`` to ``n_out`` over ``n_layers`` layers, geometric in between."""
    ratio = (n_out / n_in) ** (1.0 / n_layers)
    return [n_in] + [max(n_out, round(n_in * ratio**i)) for i in range(1, n_layers)] + [n_out]


def phase_groups(n_frames: int, stride: int) -> list[torch.Tensor]:
    """Frame indices of each phase ``p, p+stride, …`` (p < stride), grouped so phases of equal length share
    a tensor ``[n_phases_in_group, length]``."""
    groups: dict[int, list[torch.Tensor]] = {}
    for p in range(min(stride, n_frames)):
        idx = torch.arange(p, n_frames, stride)
        groups.setdefault(len(idx), []).append(idx)
    return [torch.stack(g) for g in groups.values()]


def window_starts(n_steps: int, half: int) -> tuple[torch.Tensor, int]:
    """Start of the window of each step ``[n_steps]`` and the window length ``W = min(2·half+1, n_steps)``.

    A step's window is ``half`` steps either side of it, shifted inside the sequence at its ends, so every
    window has the same length and a sequence of at most ``W`` steps is a single window.
    """
    width = min(2 * half + 1, n_steps)
    starts = (torch.arange(n_steps) - half).clamp(0, n_steps - width)
    return starts, width


class BLSTM(nn.Module):
    """Stacked bidirectional LSTM over a strided sequence, with dropout on its inputs.

    ``stride`` s: the LSTM steps through frames ``p, p+s, p+2s, …`` (each phase p separately), so in
    windowed mode ``half`` steps either side cover ``half·s`` frames.
    """

    def __init__(self, n_in: int, hidden: int, layers: int, dropout: float, stride: int = 1) -> None:
        super().__init__()
        self.drop = nn.Dropout(dropout)
        self.lstm = nn.LSTM(n_in, hidden, num_layers=layers, bidirectional=True, batch_first=True, dropout=dropout)
        self.stride = stride
        self.n_out = 2 * hidden

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        """Sequence mode: ``codes [B, T, F]`` → ``[B, T, 2H]``, one pass over each phase of the whole clip."""
        if self.stride == 1:
            return self.lstm(self.drop(codes))[0]
        b, t, f = codes.shape
        out = codes.new_empty(b, t, self.n_out)
        for idx in phase_groups(t, self.stride):
            n_ph, length = idx.shape
            seq = codes[:, idx.reshape(-1)].reshape(b * n_ph, length, f)
            res, _ = self.lstm(self.drop(seq))
            out[:, idx.reshape(-1)] = res.reshape(b, n_ph * length, self.n_out)
        return out

    def windowed(self, codes: torch.Tensor, half: int, chunk: int = 2048) -> torch.Tensor:
        """Windowed mode: ``codes [T, F]`` of one clip → ``[T, 2H]``; the output at frame t comes from an LSTM
        pass over only the ``2·half+1`` steps around t (see ``window_starts``), batched ``chunk`` windows at a
        time."""
        t = codes.shape[0]
        out = codes.new_empty(t, self.n_out)
        for idx in phase_groups(t, self.stride):
            starts, width = window_starts(idx.shape[1], half)
            gather = idx[:, starts[:, None] + torch.arange(width)]  # [n_ph, n, W] frame indices
            centre = idx  # [n_ph, n] the frame each window is for
            pos = (torch.arange(idx.shape[1]) - starts).expand_as(idx)
            gather, centre, pos = gather.reshape(-1, width), centre.reshape(-1), pos.reshape(-1)
            for s in range(0, len(centre), chunk):
                res, _ = self.lstm(self.drop(codes[gather[s : s + chunk]]))
                sel = torch.arange(len(res))
                out[centre[s : s + chunk]] = res[sel, pos[s : s + chunk]]
        return out


def unfold_taps(x: torch.Tensor, half: int) -> torch.Tensor:
    """``x [B, T, C]`` → ``[B, C, T, K]``: for each frame the ``K = 2·half+1`` samples around it, edges padded
    with the nearest frame (as ``gaussian_filter1d(mode="nearest")``)."""
    xc = x.transpose(1, 2)  # [B, C, T]
    padded = torch.cat([xc[..., :1].expand(-1, -1, half), xc, xc[..., -1:].expand(-1, -1, half)], dim=-1)
    return padded.unfold(-1, 2 * half + 1, 1)


def gaussian_weights(log_sigma: torch.Tensor, half: int) -> torch.Tensor:
    """Normalised Gaussian tap weights ``[B, C, T, K]`` from ``log σ [B, C, T]`` (σ in frames)."""
    k = torch.arange(-half, half + 1, dtype=log_sigma.dtype, device=log_sigma.device)
    inv_var = torch.exp(-2.0 * log_sigma).unsqueeze(-1)
    return torch.softmax(-0.5 * k * k * inv_var, dim=-1)


def pad_nearest(x: torch.Tensor, half: int) -> torch.Tensor:
    """``x [B, T, C]`` with ``half`` copies of its first and last frames added along time, ``[B, T + 2·half, C]``."""
    return torch.cat([x[:, :1].expand(-1, half, -1), x, x[:, -1:].expand(-1, half, -1)], dim=1)


def softmax_filter(
    x: torch.Tensor, tap_logit: Callable[[int], torch.Tensor], half: int, max_logit: torch.Tensor
) -> torch.Tensor:
    """Per-channel, per-frame FIR filter applied tap by tap: ``x [B, T, C]`` →
    ``out[t, c] = Σ_k w_k[t, c] · x[t + k, c]`` with ``w = softmax_k(tap_logit(k))``, ``k = -half … half``,
    edges padded with the nearest frame. ``tap_logit(k)`` gives the logits ``[B, T, C]`` of tap k and
    ``max_logit [B, T, C]`` their maximum over k (keeps the exponentials finite). Memory is a few
    ``[B, T, C]`` arrays: the ``[B, C, T, K]`` taps are never formed."""
    n = x.shape[1]
    padded = pad_nearest(x, half)
    num = torch.zeros_like(x)
    den = torch.zeros_like(x)
    in_place = not torch.is_grad_enabled() or not (x.requires_grad or max_logit.requires_grad)
    for k in range(-half, half + 1):
        if in_place:  # inference: no temporaries beyond the weights of one tap
            w = torch.sub(tap_logit(k), max_logit).exp_()
            num.addcmul_(w, padded[:, half + k : half + k + n])
            den.add_(w)
            continue
        w = torch.exp(tap_logit(k) - max_logit)
        num = num + w * padded[:, half + k : half + k + n]
        den = den + w
    return num / den


def gaussian_filter(x: torch.Tensor, log_sigma: torch.Tensor, half: int) -> torch.Tensor:
    """``x [B, T, C]`` filtered by the normalised Gaussian of ``log σ [B, T, C]`` (σ in frames, one per frame
    and channel) over ``2·half+1`` taps, edges padded with the nearest frame.

    Tap by tap and symmetric: with ``q = exp(-1/2σ²)`` the weight of taps ±k is ``q^(k²)``, built by products
    (``q^((k+1)²) = q^(k²) · q^(2k+1)``), so a tap costs a few multiply-adds on ``[B, T, C]`` arrays and no
    exponential; the ``[B, C, T, K]`` kernels are never formed."""
    n = x.shape[1]
    padded = pad_nearest(x, half)
    q = torch.exp(-0.5 * torch.exp(-2.0 * log_sigma))
    q2 = q * q
    weight, ratio = torch.ones_like(q), q
    num, den = x, torch.ones_like(q)
    for k in range(1, half + 1):
        weight = weight * ratio
        ratio = ratio * q2
        num = num + weight * (padded[:, half + k : half + k + n] + padded[:, half - k : half - k + n])
        den = den + 2.0 * weight
    return num / den


def init_log_sigma_bias(layer: nn.Linear, sigma_frames: float) -> None:
    """Start a σ head near ``sigma_frames`` everywhere: small weights, bias ``log σ``."""
    nn.init.uniform_(layer.weight, -1e-3, 1e-3)
    nn.init.constant_(layer.bias, math.log(sigma_frames))


def dense_layers(seq: nn.Module) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """``(weightᵀ, bias, tanh after)`` of each Linear of an ``mlp`` (an Identity gives none), as float32 numpy
    arrays for the numpy and ONNX streaming kernels."""
    mods = list(seq) if isinstance(seq, nn.Sequential) else []
    out = []
    for i, mod in enumerate(mods):
        if isinstance(mod, nn.Linear):
            tanh = i + 1 < len(mods) and isinstance(mods[i + 1], nn.Tanh)
            weight_t = np.ascontiguousarray(mod.weight.detach().numpy().astype(np.float32).T)
            out.append((weight_t, mod.bias.detach().numpy().astype(np.float32), tanh))
    return out
