"""NN ablation of the EBF paper (Sec. 4.1): a feed-forward network of 6 dense layers (tanh except the last)
from the ``2·half+1``-frame window of inputs (scored channels + root angular velocity) to the cleaned
channels of the centre frame. It has no recurrence, so sequence and windowed modes are the same computation.
``norm`` as for EBF (``base.NORMS``): the inputs and the output's scale come from the corpus (default) or from each
clip (``"clip"``, ``"both"``), so the ablation can take EBF's recipe as it is.
"""

from __future__ import annotations

import torch

from mocapnet.nn.base import NORMS, CleanerModule, n_inputs
from mocapnet.nn.layers import mlp, unfold_taps


class WindowMLP(CleanerModule):
    """Dense denoiser over a ``2·half+1``-frame window for ``n_channels`` scored channels (degrees)."""

    def __init__(
        self,
        n_channels: int,
        widths: tuple[int, ...] = (256, 256, 128, 128, 128),
        half: int = 15,
        dropout: float = 0.0,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        lr_patience: int = 4,
        lr_schedule: str = "plateau",
        skeleton_hash: str = "",
        fps: float = 0.0,
        corpus: str = "",
        norm: str = "corpus",
    ) -> None:
        super().__init__(n_channels, lr, weight_decay, lr_patience)
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        self.save_hyperparameters()
        n_in = n_inputs(n_channels, norm) * (2 * half + 1)
        self.drop = torch.nn.Dropout(dropout)
        self.net = mlp([n_in, *widths, n_channels], last_activation=False)
        torch.nn.init.zeros_(self.net[-1].weight)
        torch.nn.init.zeros_(self.net[-1].bias)

    def forward(
        self, filled: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """``filled [B, T, C]`` degrees, ``angvel [B, T, 3]`` rad/s → cleaned ``[B, T, C]`` degrees; ``stats``: a
        clip's statistics (``norm="clip"``/``"both"``; default: computed from ``filled``).

        The network predicts the centre frame's pose in normalised units; the result is put on the same
        360° branch as the input so it stays continuous with the unwrapped channels."""
        stats = self.input_stats(filled, angvel, stats)
        feats = self.input_features(filled, angvel, stats)
        windows = unfold_taps(feats, self.hparams.half).permute(0, 2, 1, 3)  # [B, T, F, K]
        out = self.net(self.drop(windows.flatten(2)))
        pred = stats["center"] + out * stats["scale"]
        # ``filled + kinematics.wrap_deg(pred - filled)`` up to float32 rounding; kept bit for bit for the
        # trained checkpoints' figures.
        return filled + torch.remainder(pred - filled + 180.0, 360.0) - 180.0

    def predict_batch(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self(batch["filled"], batch["angvel"], batch if "scale" in batch else None)

    def windowed(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        return self(filled[None], angvel[None])[0]
