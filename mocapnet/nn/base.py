"""What every cleaning network shares: normaliser buffers, skeleton metadata in its hyper-parameters, the
optimiser, and validation that accumulates one RMS error over a whole validation set.

A batch is a dict of float32 tensors (see ``mocapnet.nn.data``): ``filled [B, T, C]`` the corrupted scored
channels with gaps linearly interpolated (degrees), ``mask [B, T, C]`` True where missing, ``clean [B, T, C]``
the truth (degrees), ``angvel [B, T, 3]`` the root angular velocity (rad/s); optionally the clip statistics
of ``NORM_KEYS`` (``[B, 1, C]``, ``[B, 1, C]``, ``[B, 1, 3]``) that a ``norm="clip"``/``"both"`` network
normalises with.

Input normalisation (``norm`` hyper-parameter of the networks that offer it, default ``"corpus"``):

* ``"corpus"``: fixed statistics of the training clips, kept as buffers (``features.Normaliser``);
* ``"clip"``: each clip's own statistics of its (noisy) input, ``clip_statistics``: circular centre and std
  per channel, RMS of the root angular velocity. Protocol noise is ``K·σ_c`` with ``σ_c`` the clip's own
  std, so after dividing by the clip's std every clip shows the network the same relative noise, whatever its
  corpus, performer or amplitude;
* ``"both"``: the corpus-normalised and the clip-normalised inputs side by side (corpus first; the clip's
  statistics otherwise, e.g. for the bias bound): relative noise looks alike in every clip, as with ``"clip"``,
  and absolute noise (a fixed number of cm) keeps its size, as with ``"corpus"``.

Delta features (``deltas`` hyper-parameter of EBF, default ``"off"``): ``"add"`` appends each channel's central
first and second differences divided by the channel's scale (``frame_deltas``, 2C more columns); ``"only"`` feeds
them instead of the normalised angles (a pose-free input: the network sees how each channel moves, never where it
is; the angular velocity stays). Offline only: the streaming kernels refuse such a network.

Angle features (``sincos`` hyper-parameter, default False): with it, the sine and cosine of every scored
channel (the raw angle, not normalised) follow the normalised inputs: a representation without the ±180° wrap
that the Euler values have, 2C more columns.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any

import lightning as L
import numpy as np
import torch

from mocapnet.kinematics import wrap_deg
from mocapnet.nn.features import MIN_SCALE_DEG, Normaliser

#: Input normalisation modes (module docstring).
NORMS = ("corpus", "clip", "both")
#: Batch keys of a clip's input statistics (``clip_statistics``).
NORM_KEYS = ("center", "scale", "angvel_scale")


#: Delta-input modes (``deltas`` hyper-parameter, module docstring).
DELTAS = ("off", "add", "only")


def n_inputs(n_channels: int, norm: str, sincos: bool = False, deltas: str = "off") -> int:
    """Width of ``CleanerModule.input_features`` for ``n_channels`` scored channels."""
    angles = 0 if deltas == "only" else n_channels * (2 if norm == "both" else 1)
    return (
        angles
        + 3 * (2 if norm == "both" else 1)
        + (2 * n_channels if sincos else 0)
        + (2 * n_channels if deltas != "off" else 0)
    )


def frame_deltas(filled: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Central first and second differences of scored channels ``[..., T, C]`` (degrees, each step wrapped into
    ±180) divided by ``scale`` (``[..., 1, C]`` or ``[C]`` degrees), clipped to ±8 → ``[..., T, 2C]``; a step
    beyond either end counts as 0. Pose-free inputs: they show how a channel moves, not where it is."""
    step = wrap_deg(filled[..., 1:, :] - filled[..., :-1, :])
    pad = torch.zeros_like(filled[..., :1, :])
    ahead, behind = torch.cat([step, pad], dim=-2), torch.cat([pad, step], dim=-2)
    return torch.cat([(ahead + behind) / (2 * scale), (ahead - behind) / scale], dim=-1).clamp(-8.0, 8.0)


def uses_clip_statistics(model: torch.nn.Module) -> bool:
    """Whether ``model`` normalises its inputs with each clip's statistics (``norm`` ``"clip"`` or ``"both"``)."""
    return model.hparams.get("norm", "corpus") != "corpus"


def clip_statistics(filled: torch.Tensor, angvel: torch.Tensor) -> dict[str, torch.Tensor]:
    """A clip's own input statistics, reduced over time (dim -2, kept): ``filled [..., T, C]`` (degrees) →
    ``center [..., 1, C]`` circular mean (degrees), ``scale [..., 1, C]`` std after wrapping into
    ``center ± 180`` (degrees, at least ``MIN_SCALE_DEG``); ``angvel [..., T, 3]`` (rad/s) → ``angvel_scale
    [..., 1, 3]`` RMS (at least 1e-3). The same formulas as ``features.Normaliser.fit`` on one clip."""
    rad = torch.deg2rad(filled)
    center = torch.rad2deg(torch.atan2(rad.sin().mean(-2, keepdim=True), rad.cos().mean(-2, keepdim=True)))
    wrapped = wrap_deg(filled - center)
    scale = wrapped.std(-2, unbiased=False, keepdim=True).clamp(min=MIN_SCALE_DEG)
    angvel_scale = angvel.square().mean(-2, keepdim=True).sqrt().clamp(min=1e-3)
    return {"center": center, "scale": scale, "angvel_scale": angvel_scale}


def input_features_numpy(
    filled: np.ndarray,
    angvel: np.ndarray,
    stats: tuple[np.ndarray, np.ndarray, np.ndarray],
    corpus: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    sincos: bool = False,
) -> np.ndarray:
    """Numpy twin of ``CleanerModule.input_features`` without a mask (the streaming kernels): scored channels
    ``[N, C]`` (degrees) and root angular velocity ``[N, 3]`` (rad/s) → ``[N, n_inputs(C, norm, sincos)]`` float32,
    normalised with ``stats`` = ``(center [C], scale [C], angvel_scale [3])`` after the same with ``corpus``
    (the corpus buffers, for ``norm="both"``) when given; then sine and cosine of ``filled`` (``sincos``)."""
    parts = []
    for center, scale, angvel_scale in ([] if corpus is None else [corpus]) + [stats]:
        parts += [np.clip(wrap_deg(filled - center) / scale, -8.0, 8.0), np.clip(angvel / angvel_scale, -8.0, 8.0)]
    if sincos:
        rad = np.deg2rad(filled)
        parts += [np.sin(rad), np.cos(rad)]
    return np.concatenate(parts, axis=-1).astype(np.float32)


class CleanerModule(L.LightningModule, ABC):
    """Base LightningModule. Subclasses set ``val_metric`` (the logged name), implement ``forward`` (sequence
    mode), ``windowed`` and ``loss_terms`` / ``scored``."""

    val_metric = "val/angle_err_deg"

    def __init__(self, n_channels: int, lr: float, weight_decay: float, lr_patience: int) -> None:
        """``lr`` Adam learning rate; ``lr_patience`` epochs without improvement before it is halved (schedule
        ``plateau``). Subclasses may add ``lr_schedule="cosine"`` to their hyper-parameters: see
        ``scheduled_lr``."""
        super().__init__()
        self.register_buffer("center", torch.zeros(n_channels))
        self.register_buffer("scale", torch.ones(n_channels))
        self.register_buffer("angvel_scale", torch.ones(3))
        self._sse = 0.0
        self._count = 0

    def set_normaliser(self, norm: Normaliser) -> None:
        """Copy training-set statistics into the buffers (saved with every checkpoint)."""
        self.center.copy_(torch.as_tensor(norm.center, dtype=torch.float32))
        self.scale.copy_(torch.as_tensor(norm.scale, dtype=torch.float32))
        self.angvel_scale.copy_(torch.as_tensor(norm.angvel_scale, dtype=torch.float32))

    def input_stats(
        self, filled: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None
    ) -> dict[str, torch.Tensor]:
        """The statistics the inputs are normalised with (``NORM_KEYS``): the corpus buffers (``norm="corpus"``),
        else ``stats`` when given (a clip's statistics computed elsewhere, e.g. over a whole clip cut into
        chunks), else ``clip_statistics(filled [..., T, C], angvel [..., T, 3])``."""
        if self.hparams.get("norm", "corpus") == "corpus":
            return {"center": self.center, "scale": self.scale, "angvel_scale": self.angvel_scale}
        if stats is not None:
            return {k: stats[k] for k in NORM_KEYS}
        return clip_statistics(filled, angvel)

    def normalise(self, x: torch.Tensor, stats: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Scored channels ``[..., C]`` (degrees) → wrapped into ``center ± 180``, centred, scaled, clipped to
        ±8 (so a pose far outside the training range cannot saturate the network). ``stats``: from
        ``input_stats`` (default: the corpus buffers)."""
        center, scale = (self.center, self.scale) if stats is None else (stats["center"], stats["scale"])
        return (wrap_deg(x - center) / scale).clamp(-8.0, 8.0)

    def angvel_features(self, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Root angular velocity ``[..., 3]`` (rad/s) → scaled, clipped to ±8 (``stats`` as in ``normalise``)."""
        return (angvel / (self.angvel_scale if stats is None else stats["angvel_scale"])).clamp(-8.0, 8.0)

    def input_features(
        self,
        filled: torch.Tensor,
        angvel: torch.Tensor,
        stats: dict[str, torch.Tensor],
        mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Scored channels ``[..., T, C]`` (degrees) and root angular velocity ``[..., T, 3]`` (rad/s) →
        ``[..., T, n_inputs(C, …)]``: both normalised with ``stats`` (from ``input_stats``), after the same with
        the corpus buffers for ``norm="both"``. ``mask [..., T, C]`` (EBD) goes between the channels and the
        angular velocity of the ``stats`` part (C more columns). With the ``sincos`` hyper-parameter the sine
        and cosine of ``filled`` follow (2C more columns); with ``deltas`` the differences of ``frame_deltas``
        come last (2C more columns; ``"only"`` drops the ``stats``-normalised angles). The deltas at a frame read
        its neighbours, so a window's inputs depend on one frame beyond it on each side where the caller passes
        those frames (windowed mode and ``EBF.predict_chunked`` compute the inputs over the whole clip or span).
        ``n_inputs(C, norm, sincos, deltas)`` columns in all."""
        extra = [] if mask is None else [mask.to(filled.dtype)]
        deltas = self.hparams.get("deltas", "off")
        angles = [] if deltas == "only" else [self.normalise(filled, stats)]
        parts = [*angles, *extra, self.angvel_features(angvel, stats)]
        if self.hparams.get("norm", "corpus") == "both":
            parts = [self.normalise(filled), self.angvel_features(angvel), *parts]
        if self.hparams.get("sincos", False):
            rad = torch.deg2rad(filled)
            parts += [rad.sin(), rad.cos()]
        if deltas != "off":
            parts.append(frame_deltas(filled, stats["scale"]))
        return torch.cat(parts, dim=-1)

    @property
    def loss_in_degrees(self) -> bool:
        """Whether ``loss_terms`` gives squared degrees (then ``train/rms_deg`` is logged)."""
        return True

    def scored(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The boolean selection ``[B, T, C]`` the loss and the validation error average over: every sample."""
        return torch.ones_like(batch["mask"])

    def loss_terms(self, batch: dict[str, torch.Tensor], pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Squared errors (degrees²) and the boolean selection ``[B, T, C]`` they are averaged over (``scored``)."""
        return (pred - batch["clean"]) ** 2, self.scored(batch)

    @abstractmethod
    def predict_batch(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Sequence-mode output ``[B, T, C]`` (degrees) for a batch."""

    @abstractmethod
    def windowed(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        """Windowed-mode output ``[T, C]`` for one clip (``filled``, ``mask`` ``[T, C]``, ``angvel [T, 3]``)."""

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        sq, sel = self.loss_terms(batch, self.predict_batch(batch))
        loss = (sq * sel).sum() / sel.sum().clamp(min=1)
        self.log("train/loss", loss, prog_bar=True, batch_size=batch["clean"].shape[0])
        if self.loss_in_degrees:
            self.log("train/rms_deg", loss.detach().sqrt(), batch_size=batch["clean"].shape[0])
        return loss

    def on_validation_epoch_start(self) -> None:
        self._sse, self._count = 0.0, 0

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        pred = self.predict_batch(batch)
        diff = wrap_deg(pred - batch["clean"])
        sel = self.scored(batch)
        self._sse += float((diff**2 * sel).sum())
        self._count += int(sel.sum())

    def on_validation_epoch_end(self) -> None:
        totals = torch.tensor([self._sse, float(self._count)], dtype=torch.float64, device=self.device)
        totals = self.trainer.strategy.reduce(totals, reduce_op="sum") if self.trainer.world_size > 1 else totals
        value = float(np.sqrt(float(totals[0]) / max(float(totals[1]), 1.0)))
        self.log(self.val_metric, value, prog_bar=True, sync_dist=True)

    def configure_optimizers(self) -> dict[str, Any]:
        opt = torch.optim.Adam(self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        schedule = self.hparams.get("lr_schedule", "plateau")
        if schedule not in ("plateau", "cosine"):
            raise ValueError(f"lr_schedule must be 'plateau' or 'cosine', got {schedule!r}")
        if schedule == "cosine":
            return {"optimizer": opt}
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=self.hparams.lr_patience)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": self.val_metric}}

    def budget_fraction(self) -> float:
        """Fraction of the training budget spent, 0 … 1: wall-clock time over ``trainer.max_time`` when one is
        set (Lightning's Timer keeps the elapsed time across resumes), else steps over the planned steps."""
        from lightning.pytorch.callbacks import Timer

        timers = [c for c in self.trainer.callbacks if isinstance(c, Timer) and c._duration]
        if timers:
            return min(1.0, timers[0].time_elapsed("train") / timers[0]._duration)
        return min(1.0, self.global_step / max(float(self.trainer.estimated_stepping_batches), 1.0))

    def scheduled_lr(self, fraction: float) -> float:
        """Cosine schedule over the budget: linear warm-up over the first 2 %, then ``lr`` decaying to
        ``lr / 50`` at the end of the budget."""
        lr, warm = float(self.hparams.lr), 0.02
        if fraction < warm:
            return lr * (0.1 + 0.9 * fraction / warm)
        floor = lr / 50.0
        return floor + 0.5 * (lr - floor) * (1.0 + math.cos(math.pi * (fraction - warm) / (1.0 - warm)))

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        if self.hparams.get("lr_schedule", "plateau") != "cosine":
            return
        lr = self.scheduled_lr(self.budget_fraction())
        for group in self.trainer.optimizers[0].param_groups:
            group["lr"] = lr
        self.log("lr", lr, batch_size=1)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["mocapnet_model"] = type(self).__name__
        checkpoint["torch_rng_state"] = torch.get_rng_state()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """When a trainer resumes from a checkpoint, continue its dropout random stream (a resumed run then
        matches an uninterrupted one); plain loading for inference leaves the global generator alone."""
        if self._trainer is not None and "torch_rng_state" in checkpoint:
            torch.set_rng_state(checkpoint["torch_rng_state"])
