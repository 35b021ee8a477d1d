"""The parse cache is data, not code: no pickle, content-hash keys, checksums, rebuilt when damaged."""

from __future__ import annotations

import os
import pickle
import warnings

import numpy as np
import pytest

from mocapnet.corpus import load_corpus
from mocapnet.io.bvh import format_bvh
from mocapnet.safe_cache import CacheError, read_cache, write_cache


class _RunsCode:
    """Unpickling this would create the marker file: proof that a cache ran code."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture()
def corpus_folder(tmp_path, monkeypatch, cmu):
    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "clips"
    folder.mkdir()
    for i in range(3):
        part = cmu.channels[100 * i : 100 * i + 80]
        (folder / f"walk_{i}.bvh").write_text(format_bvh(cmu.with_channels(part)))
    return folder


def _cache_files(tmp_path):
    return sorted((tmp_path / "cache").glob("*.npz"))


def _same(a, b) -> bool:
    return [m.name for m in a.motions] == [m.name for m in b.motions] and all(
        np.array_equal(x.channels, y.channels) and np.array_equal(x.skeleton.offsets, y.skeleton.offsets)
        for x, y in zip(a.motions, b.motions)
    )


def test_cache_round_trips_exactly_and_is_not_a_pickle(corpus_folder, tmp_path):
    first = load_corpus(corpus_folder, progress=False)
    (entry,) = _cache_files(tmp_path)
    assert entry.read_bytes()[:2] == b"PK"  # a zip of .npy arrays, not a pickle stream
    again = load_corpus(corpus_folder, progress=False)
    fresh = load_corpus(corpus_folder, progress=False, use_cache=False)
    assert _same(first, again) and _same(again, fresh)
    assert again.motions[0].skeleton.topology() == fresh.motions[0].skeleton.topology()


def test_planted_pickle_runs_nothing_and_is_rebuilt(corpus_folder, tmp_path):
    truth = load_corpus(corpus_folder, progress=False)
    (entry,) = _cache_files(tmp_path)
    marker = tmp_path / "pwned"
    entry.write_bytes(pickle.dumps(_RunsCode(str(marker))))
    with pytest.warns(UserWarning, match="rebuilding the parse cache"):
        loaded = load_corpus(corpus_folder, progress=False)
    assert not marker.exists()
    assert _same(loaded, truth)
    read_cache(entry)  # rebuilt entry is valid again


def test_object_array_in_npz_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.npz"
    np.savez(path, __meta__=np.array('{"meta": "{}", "checksum": ""}'), x=np.array([_RunsCode(str(marker))]))
    with pytest.raises(CacheError):
        read_cache(path)
    assert not marker.exists()
    with pytest.raises(TypeError, match="dtype object"):
        write_cache(tmp_path / "x.npz", {"x": np.array([None])}, {})


def test_byte_flips_are_detected_or_harmless(corpus_folder, tmp_path):
    truth = load_corpus(corpus_folder, progress=False)
    (entry,) = _cache_files(tmp_path)
    original = entry.read_bytes()
    rng = np.random.default_rng(0)
    for pos in rng.integers(0, len(original), size=40):
        damaged = bytearray(original)
        damaged[pos] ^= 0xFF
        entry.write_bytes(bytes(damaged))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = load_corpus(corpus_folder, progress=False)
        assert _same(loaded, truth), f"byte {pos} flipped gave wrong data"


def test_edit_keeping_size_and_mtime_is_seen(corpus_folder, tmp_path, cmu):
    load_corpus(corpus_folder, progress=False)
    target = corpus_folder / "walk_1.bvh"
    st = target.stat()
    text = target.read_text()
    lines = text.splitlines(keepends=True)
    # Same length: swap the last two motion lines (different values, same byte count).
    lines[-1], lines[-2] = lines[-2], lines[-1]
    edited = "".join(lines)
    assert len(edited) == len(text) and edited != text
    target.write_text(edited)
    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
    loaded = load_corpus(corpus_folder, progress=False)
    fresh = load_corpus(corpus_folder, progress=False, use_cache=False)
    assert _same(loaded, fresh)


def test_unwritable_cache_only_warns(corpus_folder, tmp_path, monkeypatch):
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("x")
    monkeypatch.setenv("MOCAPNET_CACHE", str(blocker / "cache"))
    with pytest.warns(UserWarning, match="cannot write the cache"):
        corpus = load_corpus(corpus_folder, progress=False)
    assert len(corpus.motions) == 3


def test_hidden_partial_outputs_are_not_corpus_files(corpus_folder):
    (corpus_folder / ".walk_9.bvh.x1y2.partial.bvh").write_text("HIERARCHY\nROOT")
    corpus = load_corpus(corpus_folder, progress=False, use_cache=False)
    assert [m.name for m in corpus.motions] == ["walk_0", "walk_1", "walk_2"] and not corpus.skipped
