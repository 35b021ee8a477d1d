"""The learned cleaners (torch lives here only): EBF denoiser, EBD gap filler, BF/NN ablations.

``EBF.load_from_checkpoint(path)`` is all an importer needs: hyper-parameters and the input normaliser are
in the checkpoint. ``load_model(path)`` picks the class from the checkpoint itself.
"""

from mocapnet.nn.ebd import EBD
from mocapnet.nn.ebf import EBF
from mocapnet.nn.infer import load_model
from mocapnet.nn.window_mlp import WindowMLP

__all__ = ["EBD", "EBF", "WindowMLP", "load_model"]
