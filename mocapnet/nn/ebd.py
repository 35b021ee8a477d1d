"""EBD (Encoder-Bidirectional-Decoder): fills gaps (EBF paper, Sec. 3, "Gap filling").

Gaps are first filled by linear interpolation; per frame the input is the normalised filled channels, the
missing-sample mask and the root angular velocity. The encoder (as EBF's) gives a ``code``-D vector; two
bidirectional LSTM layers of ``hidden`` units per direction step through the clip with ``stride`` frames per
step (windowed mode: ``half`` steps each way, i.e. 15 × 4 = 60 frames); a decoder of ``decoder_layers`` tanh
layers (last one linear) gives, for every channel, a correction to the interpolated value in channel scales.
The output replaces only the missing samples; observed samples pass through unchanged.
"""

from __future__ import annotations

import torch

from mocapnet.nn.base import CleanerModule
from mocapnet.nn.layers import BLSTM, mlp, tapered


class EBD(CleanerModule):
    """Encoder-Bidirectional-Decoder gap filler for ``n_channels`` scored channels (degrees)."""

    val_metric = "val/gap_err_deg"

    def __init__(
        self,
        n_channels: int,
        hidden: int = 32,
        code: int = 64,
        width: int = 128,
        encoder_layers: int = 4,
        decoder_layers: int = 4,
        dropout: float = 0.5,
        half: int = 15,
        stride: int = 4,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        lr_patience: int = 4,
        lr_schedule: str = "plateau",
        skeleton_hash: str = "",
        fps: float = 0.0,
        corpus: str = "",
    ) -> None:
        super().__init__(n_channels, lr, weight_decay, lr_patience)
        self.save_hyperparameters()
        self.encoder = mlp(tapered(2 * n_channels + 3, code, encoder_layers), last_activation=True)
        self.blstm = BLSTM(code, hidden, layers=2, dropout=dropout, stride=stride)
        self.decoder = mlp([2 * hidden] + [width] * (decoder_layers - 1) + [n_channels], last_activation=False)
        torch.nn.init.zeros_(self.decoder[-1].weight)
        torch.nn.init.zeros_(self.decoder[-1].bias)

    def features(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        """``[B, T, C]`` degrees, ``[B, T, C]`` bool, ``[B, T, 3]`` rad/s → encoder input ``[B, T, 2C + 3]``."""
        return torch.cat([self.normalise(filled), mask.to(filled.dtype), self.angvel_features(angvel)], dim=-1)

    def fill(self, filled: torch.Tensor, mask: torch.Tensor, decoded: torch.Tensor) -> torch.Tensor:
        """Missing samples ← interpolation + decoded correction × channel scale; others unchanged."""
        return torch.where(mask, filled + decoded * self.scale, filled)

    def forward(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        """Sequence mode: ``filled [B, T, C]`` (gaps interpolated, degrees), ``mask [B, T, C]``, ``angvel
        [B, T, 3]`` → ``[B, T, C]`` with the gaps synthesised."""
        decoded = self.decoder(self.blstm(self.encoder(self.features(filled, mask, angvel))))
        return self.fill(filled, mask, decoded)

    def predict_batch(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self(batch["filled"], batch["mask"], batch["angvel"])

    def windowed(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        codes = self.encoder(self.features(filled, mask, angvel))
        return self.fill(filled, mask, self.decoder(self.blstm.windowed(codes, self.hparams.half)))

    def loss_terms(self, batch: dict[str, torch.Tensor], pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Squared error over the missing samples only."""
        return (pred - batch["clean"]) ** 2, batch["mask"]
