"""The one table of learned methods: each method name, the network class a checkpoint of it holds, the
hyper-parameters that tell it apart from the other methods of that class, and the line ``mocapnet methods``
shows. Everything else reads this table: ``infer.load_model`` (class of a checkpoint), ``checkpoints`` (the
method a checkpoint serves, the EBF variants), ``methods.neural`` (registration, help, variant checks).

No torch here (``mocapnet.methods.neural`` imports this module to register the methods, and ``import
mocapnet`` must stay light); the classes themselves are named by module and class name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Variant:
    """One learned method. ``model_class``: the LightningModule class (``MODEL_MODULES`` names its module),
    stored in a checkpoint as ``mocapnet_model``; ``matches(hparams)``: whether a network of that class with
    these hyper-parameters is this method (None: the method is not a network of its own, e.g. ``ebf`` runs
    the best shipped EBF variant); ``ebf``: whether ``ebf`` may run it; ``what``: one line of help."""

    name: str
    model_class: str
    what: str
    matches: Callable[[Mapping[str, Any]], bool] | None
    ebf: bool = False


def _has_encoder(hp: Mapping[str, Any]) -> bool:
    return bool(hp.get("encoder_layers", 4))


def _free(hp: Mapping[str, Any]) -> bool:
    return hp.get("filter_shape", "gaussian") == "free"


#: Module of each network class a checkpoint may name.
MODEL_MODULES: dict[str, str] = {
    "EBF": "mocapnet.nn.ebf",
    "EBD": "mocapnet.nn.ebd",
    "WindowMLP": "mocapnet.nn.window_mlp",
}

VARIANTS: tuple[Variant, ...] = (
    Variant("ebf", "EBF", "EBF, the best shipped variant for the skeleton", None),
    Variant(
        "ebf-paper",
        "EBF",
        "EBF as in the paper: learned sigma-only Gaussian filter per channel per frame, no bias",
        lambda hp: _has_encoder(hp) and not _free(hp) and not hp.get("bias"),
        ebf=True,
    ),
    Variant(
        "ebf-bias",
        "EBF",
        "EBF with a per-channel bias (residual) output on top of the Gaussian filter",
        lambda hp: _has_encoder(hp) and not _free(hp) and bool(hp.get("bias")),
        ebf=True,
    ),
    Variant(
        "ebf-free",
        "EBF",
        "EBF with a free-shape 31-tap kernel per channel per frame (with or without the bias output)",
        lambda hp: _has_encoder(hp) and _free(hp),
        ebf=True,
    ),
    Variant(
        "ebd",
        "EBD",
        "EBD: learned gap filling, blended per gap with spline/lerp and self-checked (observed samples never change)",
        lambda hp: True,
    ),
    Variant("bf", "EBF", "BF ablation: EBF without its encoder", lambda hp: not _has_encoder(hp)),
    Variant("nn", "WindowMLP", "NN ablation: dense network over a 31-frame window", lambda hp: True),
)
BY_NAME: dict[str, Variant] = {v.name: v for v in VARIANTS}
#: The EBF variants by name (issue 11): the paper's σ-only Gaussian filter; with a per-channel bias (residual)
#: output; with a free-shape kernel (softmax over the taps, with or without the bias output).
EBF_VARIANTS: tuple[str, ...] = tuple(v.name for v in VARIANTS if v.ebf)


def method_of(model_class: str, hparams: Mapping[str, Any]) -> str:
    """The method a network of ``model_class`` with ``hparams`` serves; ValueError when none in the table."""
    for v in VARIANTS:
        if v.model_class == model_class and v.matches is not None and v.matches(hparams):
            return v.name
    raise ValueError(f"no learned method in the table for a {model_class!r} network with these hyper-parameters")


def accepts(method: str, kind: str) -> bool:
    """Whether a network serving ``kind`` (``method_of``) may run as ``method``: its own name, or ``ebf`` for
    every EBF variant."""
    return kind == method or (method == "ebf" and kind in EBF_VARIANTS)


def serves(entry: Mapping[str, Any], method: str) -> bool:
    """Whether ``checkpoints/index.json`` ``entry`` is the shipped checkpoint of ``method``: its own method
    name, or ``ebf`` for the EBF variant marked ``"ebf": true`` (the best shipped variant for its skeleton).
    A network shipped as another one's short-gap partner (``"short_for": FILE``) serves no method itself."""
    if entry.get("short_for"):
        return False
    return entry["method"] == method or (method == "ebf" and bool(entry.get("ebf")))


#: Gaps shorter than this (s) go to ``ebd``'s short-gap network (``short=``, or the shipped partner): 0.2 s is
#: where the default blend's length gate (``ebd.GapBlend.gate_s``) gives the network its full weight.
SHORT_MAX_S = 0.2

#: How far a clip's frame rate may be from a network's training rate (relative) before it counts as another
#: rate: the networks' filters and LSTMs count frames, so at another rate they act over another time span.
FPS_TOLERANCE = 0.01


def same_rate(fps: float, trained_fps: float | None) -> bool:
    """Whether ``fps`` is a network's training rate ``trained_fps`` (within ``FPS_TOLERANCE``); an unknown
    rate on either side (0 or None) counts as the same."""
    return not fps or not trained_fps or abs(fps / float(trained_fps) - 1.0) <= FPS_TOLERANCE
