"""The one method ↔ network-class table (``mocapnet.nn.variants``) and those who read it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from mocapnet.nn import variants
from mocapnet.nn.checkpoints import method_of as checkpoint_method
from mocapnet.nn.checkpoints import read_checkpoint, read_index
from mocapnet.nn.infer import MODEL_CLASSES


def test_table_is_torch_free_and_so_is_registering_the_methods():
    code = "import sys, mocapnet.nn.variants, mocapnet.methods.neural; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_every_class_and_method_comes_from_the_table():
    import mocapnet.methods.neural as neural

    assert set(MODEL_CLASSES) == set(variants.MODEL_MODULES)
    assert all(cls.__name__ == name for name, cls in MODEL_CLASSES.items())
    assert {v.model_class for v in variants.VARIANTS} <= set(variants.MODEL_MODULES)
    assert set(neural._WHAT) == set(variants.BY_NAME)
    assert variants.EBF_VARIANTS == ("ebf-paper", "ebf-bias", "ebf-free")


@pytest.mark.parametrize(
    "model_class, hparams, method",
    [
        ("EBF", {"encoder_layers": 4, "filter_shape": "gaussian", "bias": False}, "ebf-paper"),
        ("EBF", {"encoder_layers": 4, "filter_shape": "gaussian", "bias": True}, "ebf-bias"),
        ("EBF", {"encoder_layers": 4, "filter_shape": "free", "bias": False}, "ebf-free"),
        ("EBF", {"encoder_layers": 4, "filter_shape": "free", "bias": True}, "ebf-free"),
        ("EBF", {"encoder_layers": 0, "bias": True}, "bf"),
        ("EBD", {}, "ebd"),
        ("WindowMLP", {}, "nn"),
    ],
)
def test_method_of(model_class, hparams, method):
    assert variants.method_of(model_class, hparams) == method
    assert variants.accepts(method, method)
    assert variants.accepts("ebf", method) == (method in variants.EBF_VARIANTS)


def test_unknown_class_is_refused():
    with pytest.raises(ValueError, match="no learned method"):
        variants.method_of("Transformer", {})


def test_shipped_index_agrees_with_the_table():
    from mocapnet.nn.checkpoints import CHECKPOINT_DIR

    for entry in read_index():
        assert entry["method"] in variants.BY_NAME
        assert variants.BY_NAME[entry["method"]].model_class == entry["class"]
        assert checkpoint_method(read_checkpoint(CHECKPOINT_DIR / entry["file"])) == entry["method"]
