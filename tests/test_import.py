"""`import mocapnet` stays light: the data layer, baselines, kNN and extrapolation never import torch."""

import subprocess
import sys


def test_import_mocapnet_does_not_import_torch():
    code = (
        "import sys, mocapnet, mocapnet.corrupt, mocapnet.evaluate.harness, mocapnet.methods.knn, "
        "mocapnet.methods.extrapolate, mocapnet.methods.baselines; "
        "from mocapnet.methods import build_method; build_method('pca'); build_method('extrapolate+cm'); "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
