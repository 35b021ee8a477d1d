"""The learned cleaners (torch lives here only): EBF denoiser, EBD gap filler, BF/NN ablations.

``EBF.load_from_checkpoint(path)`` is all an importer needs: hyper-parameters and the input normaliser are
in the checkpoint. ``load_model(path)`` picks the class from the checkpoint itself.

The names below are imported on first use, so that the torch-free modules of this package
(``mocapnet.nn.variants``, the method table) can be imported without torch.
"""

from __future__ import annotations

import importlib
from typing import Any

from mocapnet.nn.variants import MODEL_MODULES

_LAZY = {**MODEL_MODULES, "load_model": "mocapnet.nn.infer"}
__all__ = ["EBD", "EBF", "WindowMLP", "load_model"]


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'mocapnet.nn' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)
