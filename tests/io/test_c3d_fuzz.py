"""Damaged C3D files: every seeded mutation either loads as sane markers or raises MocapFileError naming
the file, quickly (ezc3d alone takes ~56 s to refuse some damaged parameter sections and hangs on others)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mocapnet.io import MocapFileError, read_c3d
from tests.conftest import SAMPLE_C3D_NAN


def mutate(raw: bytes, rng: np.random.Generator) -> bytes:
    """Truncate, or overwrite 1-7 bytes in the header, the parameter section or anywhere."""
    kind = rng.integers(4)
    if kind == 0:
        return raw[: rng.integers(1, len(raw))]
    lo, hi = [(0, 512), (512, 512 * 12), (0, len(raw))][kind - 1]
    out = bytearray(raw)
    for _ in range(rng.integers(1, 8)):
        out[rng.integers(lo, min(hi, len(raw)))] = rng.integers(256)
    return bytes(out)


@pytest.mark.filterwarnings("ignore::mocapnet.io.c3d.TruncatedC3DWarning")
@pytest.mark.parametrize("seed", range(4))
def test_mutated_files_load_or_fail_clearly(tmp_path, seed):
    rng = np.random.default_rng(seed)
    raw = SAMPLE_C3D_NAN.read_bytes()
    for k in range(15):
        path = tmp_path / f"mutant{k}.c3d"
        path.write_bytes(mutate(raw, rng))
        start = time.perf_counter()
        try:
            m = read_c3d(path, allow_truncated=bool(k % 2))
        except MocapFileError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
        else:
            assert m.points.shape[:2] == m.visible.shape and m.fps > 0
            assert np.isfinite(m.points[m.visible]).all()
        assert time.perf_counter() - start < 5.0
