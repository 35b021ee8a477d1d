"""The learned-cleaner benchmark's bookkeeping (mocapnet.evaluate.neural_bench, scripts/bench_neural.py): the
selection rule, the results file, and that bandai1 cannot be used for selection."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from mocapnet.evaluate import neural_bench as bench

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "bench_neural.py"


def _rows(method: str, ratios: dict[str, float]) -> list[dict]:
    return [{"method": method, "corruption": c, "ratio": r} for c, r in ratios.items()]


def test_selection_score_is_the_mean_ratio_over_the_selection_corruptions():
    full = dict(zip(bench.SELECTION, (0.9, 0.8, 1.0, 1.1, 0.7, 0.9)))
    rows = _rows("a", full) + _rows("b", {c: 1.0 for c in bench.SELECTION}) + _rows("c", {"angular-0.5": 0.1})
    rows += _rows("a", {"gaps": 5.0})  # not a selection corruption: ignored
    scores = bench.selection_scores(rows)
    assert scores == pytest.approx({"a": sum(full.values()) / len(full), "b": 1.0})  # c lacks corruptions


def test_markdown_lists_quality_and_selection():
    entry = {"method": "ebf", "angle_err_deg": 1.5, "ratio": 0.75, "ratio_of": "angle_err_deg", "frames_per_s": 1e3}
    meta = {"corpus": "bandai2", "split": "val", "corruption": "angular-0.5", "clips": 3, "repeats": 1}
    result = {"command": "c", "git_commit": "g", "machine": "m", "load": "1.0", "quality": [entry | meta]}
    text = bench.markdown(result | {"selection": {"ebf": 0.75}})
    assert "| bandai2 | val | angular-0.5 | 3 × 1 | ebf | 1.500 (angle_err) | 0.750 | 1,000 |" in text
    assert "| ebf | 0.750 |" in text


def test_bandai1_cannot_be_a_selection_split():
    spec = importlib.util.spec_from_file_location("bench_neural", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with pytest.raises(SystemExit):
        module.parse_args(["--split", "val"])  # default corpora include bandai1
    with pytest.raises(SystemExit):
        module.parse_args(["--split", "val", "--corpus", "bandai1"])
    assert module.parse_args(["--split", "val", "--corpus", "bandai2", "--skip-bins"]).split == "val"
    with pytest.raises(SystemExit):  # the gap bins would score fold-0 test clips
        module.parse_args(["--split", "val", "--corpus", "bandai2"])
    with pytest.raises(ValueError, match="split"):
        bench.split_clips("bandai2", "train", 3)
    for argv in (["--split", "style:elderly"], ["--split", "style:elderly", "--corpus", "bandai1"]):
        with pytest.raises(SystemExit):
            module.parse_args(argv)
    assert (
        module.parse_args(["--split", "style:elderly", "--corpus", "bandai2", "--skip-bins"]).split == "style:elderly"
    )
    with pytest.raises(ValueError, match="style:NAME"):
        bench.check_split("style:")
    with pytest.raises(SystemExit):
        module.parse_args(["--split", "style:", "--corpus", "bandai2"])


def test_only_stream_keeps_the_other_parts(tmp_path, monkeypatch):
    """``--only stream`` reruns the streaming timing and keeps the rest of the results file."""
    spec = importlib.util.spec_from_file_location("bench_neural", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    from mocapnet.evaluate.results import read_json, write_json

    old = {"command": "c", "git_commit": "g", "machine": "m", "load": "1.0", "speed": {"streaming": {"ebf": {}}}}
    write_json(tmp_path / "neural.json", old)
    row = {"pushes": 2000, "streams": 1, "cpu_p50_ms": 0.4, "cpu_p99_ms": 0.9, "wall_p50_ms": 0.5, "wall_p99_ms": 2.0}
    timing = {"load_before": [1.0, 2.0, 3.0], "ebf": {"numpy": row, "onnx": row}, "load_after": [1.0, 2.0, 3.0]}
    monkeypatch.setattr(module, "streaming_part", lambda args: timing)
    module.main(["--only", "stream", "--out", str(tmp_path / "neural")])
    got = read_json(tmp_path / "neural.json")
    assert got["command"] == "c" and got["speed"] == {} and got["streaming"] == timing
    assert "--only stream" in got["streaming_run"]["command"]
    text = (tmp_path / "neural.md").read_text()
    assert "| ebf | onnx | 2,000 | 0.400 | 0.900 | 0.500 | 2.000 |" in text


@pytest.mark.parametrize(
    ("split", "labels", "marker"),
    [
        ("style:elderly", [f"walk_{s}" for s in ("elderly", "active", "normal")], "_elderly_"),
        ("content:run", [f"{c}_normal" for c in ("run", "walk", "wave-left-hand")], "_run_"),
    ],
)
def test_held_out_split_scores_only_its_clips_and_tunes_without_them(monkeypatch, split, labels, marker):
    """``style:NAME`` / ``content:NAME`` score clips of that style or content outside fold 0 only; the training
    clips (for gaussian-tuned) hold none of them."""
    from mocapnet.corpus import Corpus
    from mocapnet.evaluate.bvh_bench import synthetic

    base = synthetic(4, chain=True)
    names = [f"dataset-2_{label}_{i:03d}" for label in labels for i in range(10)]
    motions = [type(base)(base.skeleton, base.channels, base.fps, n) for n in names]
    corpus = Corpus("fake", Path("."), motions, {n: i % 5 for i, n in enumerate(names)})
    monkeypatch.setattr(bench, "load_corpus", lambda name, progress: corpus)
    assert bench.check_split(split) == split
    _, clips, train = bench.split_clips("fake", split, 4)
    assert len(clips) == 4 and all(marker in m.name for m in clips)
    assert all(corpus.folds[m.name] != 0 for m in clips)  # the fold-0 test clips stay unseen
    assert train and not any(marker in m.name for m in train)
    assert all(corpus.folds[m.name] not in (0, 1) for m in train)
    kind, label = split.split(":")
    with pytest.raises(ValueError, match=f"no clip of {kind} '{label}' outside"):
        only_test = Corpus("fake", Path("."), motions, {n: 0 if marker in n else 2 for n in names})
        monkeypatch.setattr(bench, "load_corpus", lambda name, progress: only_test)
        bench.split_clips("fake", split, 4)
    with pytest.raises(ValueError, match=f"{kind}:NAME"):
        bench.check_split(f"{kind}:")


def test_fast_split_is_fold_1_with_the_most_fast_movement_first(monkeypatch):
    """``fast``: fold-1 clips only, ordered by ``fast_motion`` (jittery clips first), ``--clips N`` the first N;
    bandai1 cannot be selected on with it."""
    from mocapnet.corpus import Corpus
    from mocapnet.evaluate.bvh_bench import synthetic

    base = synthetic(4, chain=True)
    rng = np.random.default_rng(0)
    smooth = np.repeat(base.channels[:1], 90, axis=0) + np.linspace(0, 30, 90)[:, None]  # 90 frames, slow
    motions, folds = [], {}
    for i in range(15):  # clip i gets jitter i / 4 degrees on every channel; folds 0..4 in turn
        channels = smooth + rng.normal(0, i / 4 + 1e-3, smooth.shape)
        motions.append(type(base)(base.skeleton, channels, base.fps, f"clip{i:02d}"))
        folds[f"clip{i:02d}"] = i % 5
    corpus = Corpus("fake", Path("."), motions, folds)
    monkeypatch.setattr(bench, "load_corpus", lambda name, progress: corpus)
    _, clips, train = bench.split_clips("fake", "fast", None)
    assert [m.name for m in clips] == ["clip11", "clip06", "clip01"]  # fold 1, most jitter first
    assert [m.name for m in bench.split_clips("fake", "fast", 2)[1]] == ["clip11", "clip06"]
    assert all(folds[m.name] not in (0, 1) for m in train)
    speeds = [bench.fast_motion(m) for m in clips]
    assert speeds == sorted(speeds, reverse=True) and speeds[-1] > 0
    spec = importlib.util.spec_from_file_location("bench_neural", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with pytest.raises(SystemExit):
        module.parse_args(["--split", "fast", "--corpus", "bandai1", "--skip-bins"])
    assert module.parse_args(["--split", "fast", "--corpus", "bandai2", "--skip-bins"]).split == "fast"
    for bad in ("0", "-3", "2.5"):
        with pytest.raises(SystemExit):
            module.parse_args(["--split", "fast", "--corpus", "bandai2", "--skip-bins", "--clips", bad])


def test_gap_corruptions_score_extra_checkpoints_of_their_family():
    """noise+gaps scores the shipped ebd+ebf and every extra ``ebd+ebf=…`` (a candidate pair was silently dropped
    before); gaps the shipped ebd and extra ``ebd=…``; the denoisers given as extras only on noise."""
    extra = ["ebf-free=a.ckpt:limit=2.5", "ebd+ebf=k.ckpt,r.ckpt", "ebd=k.ckpt:rehearse=4", "ebd+ebf"]
    assert bench.neural_methods("noise+gaps", None, extra) == ["ebd+ebf", "ebd+ebf=k.ckpt,r.ckpt"]
    assert bench.neural_methods("gaps", None, extra) == ["ebd", "ebd=k.ckpt:rehearse=4"]
    assert bench.neural_methods("angular-0.5", None, extra, shipped=False) == extra
