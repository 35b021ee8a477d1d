import json

import pytest

from mocapnet.corpus import SPLITS_DIR, content_label, load_corpus, make_folds
from mocapnet.io.bvh import format_bvh


def test_content_labels():
    assert content_label("dataset-2_walk-turn-left_active_003") == "walk-turn-left"
    assert content_label("01_01") == "01_01"
    assert content_label("walk_12") == "walk"


def test_folds_are_stratified_and_balanced():
    names = [f"dataset-2_{c}_normal_{i:03d}" for c in ("walk", "run", "wave") for i in range(23)]
    folds = make_folds(names)
    for c in ("walk", "run", "wave"):
        counts = [sum(1 for n, f in folds.items() if f == k and f"_{c}_" in n) for k in range(5)]
        assert max(counts) - min(counts) <= 1
    assert make_folds(names) == folds


def test_committed_split_covers_bandai2(shared):
    payload = json.loads((SPLITS_DIR / "bandai2.json").read_text())
    assert len(payload["folds"]) == 2902 and sorted(set(payload["folds"].values())) == [0, 1, 2, 3, 4]


def test_sample_corpus_and_split():
    corpus = load_corpus("sample", progress=False, use_cache=False)
    assert corpus.name == "sample" and len(corpus.motions) == 1
    train, val, test = corpus.split(0)  # one clip: split in time 70/15/15
    assert [m.name for m in train + val + test] == ["01_01#train", "01_01#val", "01_01#test"]
    assert [m.n_frames for m in train + val + test] == [1926, 413, 413]
    with pytest.raises(ValueError, match="fold"):
        corpus.split(5)


def test_mismatched_skeleton_is_skipped_and_cache_is_fast(tmp_path, monkeypatch, cmu, bandai):
    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "mixed"
    folder.mkdir()
    for i in range(3):
        (folder / f"walk_{i}.bvh").write_text(format_bvh(bandai))
    (folder / "cmu.bvh").write_text(format_bvh(cmu.with_channels(cmu.channels[:50])))
    with pytest.warns(UserWarning, match="skipped cmu.*does not match the corpus skeleton"):
        corpus = load_corpus(folder, progress=False)
    assert [m.name for m in corpus.motions] == ["walk_0", "walk_1", "walk_2"]
    assert corpus.skipped[0][0] == "cmu"
    assert list((tmp_path / "cache").iterdir())
    with pytest.warns(UserWarning, match="skipped cmu"):
        again = load_corpus(folder, progress=False)
    assert [m.name for m in again.motions] == [m.name for m in corpus.motions]


def test_unknown_folder():
    with pytest.raises(FileNotFoundError, match="no such corpus name or folder"):
        load_corpus("/nonexistent/folder")


def test_bandai2_second_load_is_fast(shared, tmp_path, monkeypatch):
    import time

    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path))
    load_corpus("bandai2", progress=False, limit=300)
    start = time.perf_counter()
    corpus = load_corpus("bandai2", progress=False, limit=300)
    assert time.perf_counter() - start < 1.0  # well under a second per 100 files
    assert len(corpus.motions) == 300


def test_holdout_style(tmp_path, monkeypatch, bandai):
    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "styles"
    folder.mkdir()
    for style in ("normal", "elderly"):
        for i in range(10):
            (folder / f"dataset-2_walk_{style}_{i:03d}.bvh").write_text(format_bvh(bandai))
    corpus = load_corpus(folder, progress=False)
    train, val, test = corpus.split(0, holdout_style="elderly")
    assert train and all("_elderly_" not in m.name for m in train + val)
    assert len(corpus.style_clips("elderly")) == 10
    with pytest.raises(ValueError, match="no clip of style 'tired'"):
        corpus.split(0, holdout_style="tired")


def test_holdout_content(tmp_path, monkeypatch, bandai):
    """``holdout_content`` leaves every clip of one content out of train and validation (alone or with a style)."""
    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "contents"
    folder.mkdir()
    for content in ("walk", "run"):
        for style in ("normal", "elderly"):
            for i in range(5):
                (folder / f"dataset-2_{content}_{style}_{i:03d}.bvh").write_text(format_bvh(bandai))
    corpus = load_corpus(folder, progress=False)
    assert len(corpus.content_clips("run")) == 10
    train, val, test = corpus.split(0, holdout_content="run")
    assert train and all("_run_" not in m.name for m in train + val)
    assert any("_run_" in m.name for m in corpus.motions if corpus.folds[m.name] == 0) == any(
        "_run_" in m.name for m in test
    )
    both, _, _ = corpus.split(0, holdout_style="elderly", holdout_content="run")
    assert both and all("_walk_normal_" in m.name for m in both)
    with pytest.raises(ValueError, match="no clip of content 'kick'; contents: run, walk"):
        corpus.split(0, holdout_content="kick")
