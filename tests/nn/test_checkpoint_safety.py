"""Checkpoints are data: a crafted checkpoint never runs code through any entry point, a truncated or foreign
file is a clear error (exit 2), and a shipped checkpoint is checked against its SHA-256 (issue 14, item 1)."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from mocapnet.cli import main
from mocapnet.io.atomic import MocapFileError
from mocapnet.nn import checkpoints
from mocapnet.nn.checkpoints import read_checkpoint, read_index, sha256_of
from mocapnet.nn.infer import load_model
from mocapnet.nn.train import resume_path

SAMPLE_BVH = Path(__file__).resolve().parents[2] / "mocapnet" / "data" / "bvh" / "01_01.bvh.gz"


class _Payload:
    """Unpickling this object would create ``marker`` (what an attacker's shell command stands for)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",))


def _evil_files(tmp_path: Path) -> list[tuple[Path, Path]]:
    """``(checkpoint, marker)`` pairs: a torch.save zip and a raw pickle, each with a code-running payload in
    an otherwise plausible checkpoint dict."""
    out = []
    for kind in ("zip", "raw"):
        marker = tmp_path / f"marker_{kind}"
        ckpt = {"mocapnet_model": "EBF", "hyper_parameters": {"n_channels": 3}, "state_dict": _Payload(marker)}
        path = tmp_path / f"evil_{kind}.ckpt"
        if kind == "zip":
            torch.save(ckpt, path)
        else:
            path.write_bytes(pickle.dumps(ckpt, protocol=2))
        out.append((path, marker))
    return out


def test_payload_would_run_code_if_unpickled(tmp_path):
    """The test payload is real: plain unpickling creates the marker."""
    (path, marker), _ = _evil_files(tmp_path)
    torch.load(path, weights_only=False)
    assert marker.exists()


@pytest.mark.parametrize("entry", ["clean --method", "clean --model", "clean ebd+ebf", "evaluate", "evaluate pair"])
def test_malicious_checkpoint_exits_2_and_runs_nothing(entry, tmp_path, capsys):
    out = tmp_path / "out.bvh"
    mask = tmp_path / "mask.npy"
    gaps = np.zeros((2752, 31), dtype=bool)
    gaps[100:110, 5] = True
    np.save(mask, gaps)
    for evil, marker in _evil_files(tmp_path):
        argv = {
            "clean --method": ["clean", str(SAMPLE_BVH), "-o", str(out), "--method", f"ebf={evil}"],
            "clean --model": ["clean", str(SAMPLE_BVH), "-o", str(out), "--model", str(evil)],
            "clean ebd+ebf": [
                "clean",
                str(SAMPLE_BVH),
                "-o",
                str(out),
                "--mask",
                str(mask),
                "--model",
                f"{evil},{evil}",
            ],
            "evaluate": ["evaluate", "--data", "sample", "--fold", "0", "--repeats", "1", "--method", f"ebf={evil}"],
            "evaluate pair": [
                "evaluate",
                "--data",
                "sample",
                "--corruption",
                "noise+gaps",
                "--repeats",
                "1",
                "--method",
                f"ebd+ebf={evil},{evil}",
            ],
        }[entry]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert str(evil) in err and "refused" in err
        assert not marker.exists()
        assert not out.exists()


def test_malicious_checkpoint_refused_by_every_loader(tmp_path):
    for evil, marker in _evil_files(tmp_path):
        for load in (read_checkpoint, load_model, lambda p: resume_path(str(p), tmp_path)):
            with pytest.raises(MocapFileError, match="refused"):
                load(evil)
        with pytest.raises(MocapFileError, match="refused"):
            checkpoints.export(evil, "never_written")
        assert not marker.exists()
    assert not (checkpoints.CHECKPOINT_DIR / "never_written.ckpt").exists()


def test_truncated_and_foreign_checkpoints_are_clear_errors(tmp_path, capsys):
    good = checkpoints.CHECKPOINT_DIR / read_index()[0]["file"]
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 3])
    foreign = tmp_path / "foreign.ckpt"
    foreign.write_text("HIERARCHY\nROOT Hips\n")
    a_list = tmp_path / "list.ckpt"
    torch.save([1, 2, 3], a_list)
    not_ours = tmp_path / "not_ours.ckpt"
    torch.save({"state_dict": {}}, not_ours)
    for path, message in (
        (truncated, "truncated or foreign"),
        (foreign, "truncated or foreign"),
        (a_list, "not a mocapnet checkpoint"),
        (not_ours, "not a mocapnet network"),
    ):
        with pytest.raises(MocapFileError, match=message):
            load_model(path)
        assert main(["clean", str(SAMPLE_BVH), "-o", str(tmp_path / "o.bvh"), "--model", str(path)]) == 2
        assert str(path) in capsys.readouterr().err


def test_resume_from_truncated_or_non_training_checkpoint_is_refused(tmp_path):
    ckpt_dir = tmp_path / "checkpoints"
    ckpt_dir.mkdir()
    assert resume_path("last", ckpt_dir) is None
    assert resume_path(None, ckpt_dir) is None
    good = checkpoints.CHECKPOINT_DIR / read_index()[0]["file"]
    (ckpt_dir / "last.ckpt").write_bytes(good.read_bytes()[:1000])
    with pytest.raises(MocapFileError, match="truncated"):
        resume_path("last", ckpt_dir)
    shutil.copy(good, ckpt_dir / "last.ckpt")
    with pytest.raises(MocapFileError, match="not a training checkpoint"):
        resume_path("last", ckpt_dir)


def test_shipped_checkpoints_carry_a_verified_sha256(tmp_path, monkeypatch):
    entries = read_index()
    for entry in entries:
        path = checkpoints.CHECKPOINT_DIR / entry["file"]
        assert entry["sha256"] == sha256_of(path)
        assert entry["recipe"] and entry["budget"] and entry["epochs"] >= 1
    fake_dir = tmp_path / "ckpts"
    fake_dir.mkdir()
    shutil.copy(checkpoints.INDEX, fake_dir / "index.json")
    name = entries[0]["file"]
    damaged = bytearray((checkpoints.CHECKPOINT_DIR / name).read_bytes())
    damaged[-100] ^= 0xFF
    (fake_dir / name).write_bytes(bytes(damaged))
    monkeypatch.setattr(checkpoints, "CHECKPOINT_DIR", fake_dir.resolve())
    monkeypatch.setattr(checkpoints, "INDEX", fake_dir / "index.json")
    with pytest.raises(MocapFileError, match="SHA-256"):
        read_checkpoint(fake_dir / name)


@pytest.mark.parametrize("fp16", [False, True])
def test_export_records_sha256_and_keeps_the_network(fp16, tiny, sample, tmp_path, monkeypatch):
    from tests.nn.test_neural_methods import save

    model = tiny("ebf-free", sample).eval()
    src = save(model, tmp_path / "run.ckpt")
    monkeypatch.setattr(checkpoints, "CHECKPOINT_DIR", (tmp_path / "ship").resolve())
    monkeypatch.setattr(checkpoints, "INDEX", tmp_path / "ship" / "index.json")
    dst = checkpoints.export(src, "sample_ebf_free", "cmd", recipe="r", budget="b", as_ebf=True, fp16=fp16)
    entry = read_index()[0]
    assert entry["method"] == "ebf-free" and entry["ebf"] and entry["sha256"] == sha256_of(dst)
    assert entry["weights"] == ("float16" if fp16 else "float32") and entry["recipe"] == "r"
    assert checkpoints.shipped_checkpoint("ebf", sample.skeleton) == dst
    loaded = load_model(dst)
    assert loaded.center.dtype == torch.float32
    x = torch.as_tensor(sample.channels[:64, sample.skeleton.scored_mask], dtype=torch.float32)[None]
    w = torch.zeros(1, 64, 3)
    with torch.inference_mode():
        diff = (loaded(x, w) - model(x, w)).abs().max()
    assert float(diff) < (0.05 if fp16 else 1e-5)


def test_export_refuses_a_delta_input_network_as_the_ebf(tiny, sample, tmp_path, monkeypatch):
    """The shipped ``ebf`` must stream; a network with delta inputs cannot, so it cannot serve ``ebf`` (nothing is
    written); it may still ship under its own method name."""
    from tests.nn.test_neural_methods import save

    monkeypatch.setattr(checkpoints, "CHECKPOINT_DIR", (tmp_path / "ship").resolve())
    monkeypatch.setattr(checkpoints, "INDEX", tmp_path / "ship" / "index.json")
    src = save(tiny("ebf-free", sample, norm="clip", deltas="add"), tmp_path / "d.ckpt")
    with pytest.raises(ValueError, match="delta inputs cannot serve 'ebf'"):
        checkpoints.export(src, "sample_ebf_deltas", as_ebf=True)
    assert not (tmp_path / "ship" / "sample_ebf_deltas.ckpt").exists()
    assert checkpoints.export(src, "sample_ebf_deltas").is_file()


def test_export_pairs_an_ebd_with_its_short_gap_network(tiny, sample, tmp_path, monkeypatch):
    """``export(short=FILE)`` records the pair both ways: the main entry names its partner and length, the partner
    is marked ``short_for`` and is never the lookup's answer; a partner that is not a shipped EBD of the skeleton
    is refused and nothing is written."""
    from tests.nn.test_neural_methods import save

    monkeypatch.setattr(checkpoints, "CHECKPOINT_DIR", (tmp_path / "ship").resolve())
    monkeypatch.setattr(checkpoints, "INDEX", tmp_path / "ship" / "index.json")
    short = checkpoints.export(save(tiny("ebd", sample), tmp_path / "a.ckpt"), "sample_ebd_short")
    denoiser = checkpoints.export(save(tiny("ebf-free", sample), tmp_path / "b.ckpt"), "sample_ebf")
    main_src = save(tiny("ebd", sample), tmp_path / "c.ckpt")
    for bad in ("missing.ckpt", denoiser.name):
        with pytest.raises(ValueError, match="short-gap partner"):
            checkpoints.export(main_src, "sample_ebd", short=bad)
    with pytest.raises(ValueError, match="short-gap partner"):  # a denoiser cannot have one
        checkpoints.export(save(tiny("ebf-free", sample), tmp_path / "d.ckpt"), "sample_ebf2", short=short.name)
    assert not (tmp_path / "ship" / "sample_ebd.ckpt").exists()
    assert not (tmp_path / "ship" / "sample_ebf2.ckpt").exists()
    with pytest.raises(ValueError, match="not a time > 0"):
        checkpoints.export(main_src, "sample_ebd", short=short.name, short_max_s=float("inf"))
    assert not (tmp_path / "ship" / "sample_ebd.ckpt").exists()
    main = checkpoints.export(main_src, "sample_ebd", short=short.name, short_max_s=0.25)
    entries = {e["file"]: e for e in read_index()}
    assert entries[main.name]["short"] == {"file": short.name, "max_s": 0.25}
    assert entries[short.name]["short_for"] == main.name
    assert checkpoints.shipped_checkpoint("ebd", sample.skeleton) == main
    assert checkpoints.shipped_short(sample.skeleton) == (short, 0.25)
    # the partner re-exported stays the partner; a second main for the skeleton, or a second pairing, is refused
    checkpoints.export(save(tiny("ebd", sample), tmp_path / "e.ckpt"), "sample_ebd_short")
    assert {e["file"]: e for e in read_index()}[short.name]["short_for"] == main.name
    before = (tmp_path / "ship" / "index.json").read_text()
    with pytest.raises(ValueError, match="already ships ebd"):
        checkpoints.export(save(tiny("ebd", sample), tmp_path / "f.ckpt"), "sample_ebd_other")
    with pytest.raises(ValueError, match="another frame rate"):
        checkpoints._check_export(
            "ebd",
            {"skeleton_hash": entries[main.name]["skeleton_hash"], "fps": 30.0},
            main.name,
            False,
            short.name,
            0.2,
        )
    assert (tmp_path / "ship" / "index.json").read_text() == before


def test_the_shipped_index_pairs_are_consistent():
    """The real ``index.json`` (no torch needed): every file it names exists; at most one entry serves a method
    for a skeleton; each ``short`` partner exists, points back with ``short_for`` and has the main network's
    skeleton and frame rate, and a finite length > 0."""
    entries = {e["file"]: e for e in read_index()}
    assert all((checkpoints.CHECKPOINT_DIR / f).is_file() for f in entries)
    serving = [(e["method"], e["skeleton_hash"]) for e in entries.values() if not e.get("short_for")]
    assert len(serving) == len(set(serving))
    for e in entries.values():
        if e.get("short"):
            partner = entries[e["short"]["file"]]
            assert e["method"] == partner["method"] == "ebd" and partner["short_for"] == e["file"]
            assert partner["skeleton_hash"] == e["skeleton_hash"] and partner["fps"] == e["fps"]
            assert 0 < e["short"]["max_s"] < float("inf")
        if e.get("short_for"):
            assert entries[e["short_for"]]["short"]["file"] == e["file"]


def test_numpy_scalars_are_allowed_and_arrays_refused(tmp_path):
    scalar = tmp_path / "scalar.ckpt"
    torch.save({"lr": np.float64(0.5), "n": np.int64(3)}, scalar)
    assert read_checkpoint(scalar)["lr"] == 0.5
    array = tmp_path / "array.ckpt"
    torch.save({"x": np.zeros(3)}, array)
    with pytest.raises(MocapFileError, match="refused"):
        read_checkpoint(array)
