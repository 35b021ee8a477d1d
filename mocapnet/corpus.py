"""Corpora (folders of BVH files sharing one skeleton topology), 5-fold splits and a parse cache.

Names: ``bandai2``, ``bandai1``, ``cmu120`` (PROTOCOL.md) resolve under the data root; ``sample`` is the
CMU clip shipped inside the package; any other string is a folder. The data root is ``$MOCAPNET_DATA``, else
``../shared/data`` beside the project checkout, else ``../shared/data`` from the working directory.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError
from mocapnet.io.bvh import read_bvh
from mocapnet.motion import Motion, Skeleton
from mocapnet.safe_cache import CacheError, cache_dir, content_hash, read_cache, write_cache

PACKAGE_DATA = Path(__file__).parent / "data"
SPLITS_DIR = Path(__file__).parent / "splits"
N_FOLDS = 5
TIME_SPLIT = (0.7, 0.15)  # train and validation fractions of a single-clip corpus; the rest is test
_CACHE_VERSION = 2

CORPORA = {
    "bandai2": ("bvh/bandai_namco_2", 1.0),
    "bandai1": ("bvh/bandai_namco_1", 1.0),
    "cmu120": ("bvh/cmu_cgspeed", 2.54 / 0.45),
}


def data_root() -> Path:
    """The folder holding the shared recordings (see module docstring)."""
    env = os.environ.get("MOCAPNET_DATA")
    if env:
        return Path(env)
    beside_repo = Path(__file__).resolve().parents[2] / "shared" / "data"
    if beside_repo.exists():
        return beside_repo
    return Path.cwd().parent / "shared" / "data"


def resolve(data: str | os.PathLike) -> tuple[str, Path, float | None]:
    """``(corpus name, folder, cm per unit or None)`` for a corpus name or folder."""
    text = str(data)
    if text == "sample":
        return "sample", PACKAGE_DATA / "bvh", CORPORA["cmu120"][1]
    if text in CORPORA:
        sub, unit = CORPORA[text]
        folder = data_root() / sub
        if not folder.exists() and text == "cmu120":
            folder = PACKAGE_DATA / "bvh"
        if not folder.exists():
            raise FileNotFoundError(f"corpus {text!r}: folder {folder} not found (set MOCAPNET_DATA to the data root)")
        return text, folder, unit
    folder = Path(text)
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such corpus name or folder (known names: sample, {', '.join(CORPORA)})")
    name = folder.name
    for key, (sub, unit) in CORPORA.items():
        if folder.resolve() == (data_root() / sub).resolve():
            return key, folder, unit
    return name, folder, None


def list_bvh(folder: Path) -> list[Path]:
    """BVH files of a folder (``.bvh`` and ``.bvh.gz``, case-insensitive), sorted by name; a single file is its
    own list. Hidden files (``.name``: temporary outputs of an interrupted write) are not corpus files."""
    if folder.is_file():
        return [folder]
    files = sorted(
        p for p in folder.iterdir() if p.name.lower().endswith((".bvh", ".bvh.gz")) and not p.name.startswith(".")
    )
    if not files:
        raise FileNotFoundError(f"{folder}: no .bvh or .bvh.gz files")
    return files


def clip_name(path: Path) -> str:
    return path.name.removesuffix(".gz").removesuffix(".bvh")


def content_label(name: str) -> str:
    """Motion type from a file name: Bandai ``dataset-2_{content}_{style}_{id}`` → content; else the name
    without trailing digits."""
    m = re.match(r"dataset-\d+_([^_]+)_([^_]+)_\d+", name)
    if m:
        return m.group(1)
    return re.sub(r"[_\-\d]+$", "", name) or name


def style_label(name: str) -> str:
    m = re.match(r"dataset-\d+_([^_]+)_([^_]+)_\d+", name)
    return m.group(2) if m else ""


def make_folds(names: list[str], n_folds: int = N_FOLDS, seed: int = 0) -> dict[str, int]:
    """Fold per clip, stratified by content label: within each content the clips are shuffled (fixed
    seed) and dealt round-robin, continuing the deal across contents so fold sizes stay balanced."""
    rng = np.random.default_rng(seed)
    by_content: dict[str, list[str]] = {}
    for n in sorted(names):
        by_content.setdefault(content_label(n), []).append(n)
    folds: dict[str, int] = {}
    k = 0
    for content in sorted(by_content):
        group = by_content[content]
        for i in rng.permutation(len(group)):
            folds[group[i]] = k % n_folds
            k += 1
    return folds


def load_folds(corpus: str, names: list[str]) -> dict[str, int]:
    """The committed split of a named corpus (``mocapnet/splits/<corpus>.json``) or, for other folders, the
    same stratified split computed on the fly."""
    path = SPLITS_DIR / f"{corpus}.json"
    if path.exists():
        folds = json.loads(path.read_text())["folds"]
        missing = [n for n in names if n not in folds]
        if not missing:
            return {n: folds[n] for n in names}
        warnings.warn(
            f"{path}: {len(missing)} files not in the committed split (e.g. {missing[0]}); recomputing", stacklevel=2
        )
    return make_folds(names)


def time_segments(motion: Motion, fractions: tuple[float, float] = TIME_SPLIT) -> tuple[Motion, Motion, Motion]:
    """Cut one clip in time into (train, validation, test) of ``fractions[0]``, ``fractions[1]`` and the
    remaining fraction of its frames; names get ``#train`` / ``#val`` / ``#test``."""
    n = motion.n_frames
    a = int(round(fractions[0] * n))
    b = int(round((fractions[0] + fractions[1]) * n))
    parts = ((0, a, "train"), (a, b, "val"), (b, n, "test"))
    return tuple(  # type: ignore[return-value]
        Motion(motion.skeleton, motion.channels[s:e], motion.fps, f"{motion.name}#{tag}") for s, e, tag in parts
    )


@dataclass
class Corpus:
    """Clean motions of one skeleton topology, with their folds."""

    name: str
    folder: Path
    motions: list[Motion]
    folds: dict[str, int]
    skipped: list[tuple[str, str]] = field(default_factory=list)

    def split(
        self,
        fold: int,
        holdout_style: str | None = None,
        time_split: tuple[float, float] = TIME_SPLIT,
        holdout_content: str | None = None,
    ) -> tuple[list[Motion], list[Motion], list[Motion]]:
        """``(train, validation, test)`` for ``fold``: test = fold k, validation = fold k+1 mod 5, train =
        the other three. ``holdout_style`` (e.g. ``"elderly"``) removes every clip of that style from train
        and validation, for the unseen-style check (score it with ``style_clips``); ``holdout_content`` (e.g.
        ``"run"``) every clip of that content, for the unseen-content check (``content_clips``).

        A corpus of a single clip (``cmu120``, ``sample``) is split in time instead, whatever the fold: by
        default the first 70 % of its frames train, the next 15 % validate, the last 15 % test (``time_split``
        gives the first two fractions; ``#train``/``#val``/``#test`` are appended to the name)."""
        if not 0 <= fold < N_FOLDS:
            raise ValueError(f"fold must be in 0..{N_FOLDS - 1}, got {fold}")
        if len(self.motions) == 1:
            train, val, test = time_segments(self.motions[0], time_split)
            return [train], [val], [test]
        if holdout_style is not None and not self.style_clips(holdout_style):
            styles = sorted({style_label(m.name) for m in self.motions})
            raise ValueError(f"{self.name}: no clip of style {holdout_style!r}; styles: {', '.join(styles)}")
        if holdout_content is not None and not self.content_clips(holdout_content):
            contents = sorted({content_label(m.name) for m in self.motions})
            raise ValueError(f"{self.name}: no clip of content {holdout_content!r}; contents: {', '.join(contents)}")
        val_fold = (fold + 1) % N_FOLDS

        def learnable(m: Motion) -> bool:
            if holdout_content is not None and content_label(m.name) == holdout_content:
                return False
            return holdout_style is None or style_label(m.name) != holdout_style

        train = [m for m in self.motions if self.folds[m.name] not in (fold, val_fold) and learnable(m)]
        val = [m for m in self.motions if self.folds[m.name] == val_fold and learnable(m)]
        test = [m for m in self.motions if self.folds[m.name] == fold]
        return train, val, test

    def style_clips(self, style: str) -> list[Motion]:
        """Every clip of one style label (Bandai file names ``dataset-N_{content}_{style}_{id}``)."""
        return [m for m in self.motions if style_label(m.name) == style]

    def content_clips(self, content: str) -> list[Motion]:
        """Every clip of one content label (``content_label``: Bandai's ``{content}``, e.g. ``run``)."""
        return [m for m in self.motions if content_label(m.name) == content]

    @property
    def n_frames(self) -> int:
        return sum(m.n_frames for m in self.motions)


def _cache_key(files: list[Path], unit: float | None) -> str:
    """Content hash of the corpus files (every byte), the unit and the cache version."""
    return content_hash(files, salt=f"v{_CACHE_VERSION}|{unit}")


def _pack(motions: list[Motion], skipped: list[tuple[str, str]], key: str) -> tuple[dict, dict]:
    """Arrays and JSON header of a parsed corpus (all motions share one topology)."""
    sk = motions[0].skeleton
    arrays = {
        "channels": np.concatenate([m.channels for m in motions]),
        "lengths": np.array([m.n_frames for m in motions], dtype=np.int64),
        "offsets": np.stack([m.skeleton.offsets for m in motions]),
        "end_sites": np.stack([np.asarray(m.skeleton.end_sites, dtype=np.float64).reshape(-1, 3) for m in motions]),
        "cm_per_unit": np.array([m.skeleton.cm_per_unit for m in motions], dtype=np.float64),
        "fps": np.array([m.fps for m in motions], dtype=np.float64),
    }
    meta = {
        "key": key,
        "names": [m.name for m in motions],
        "joints": list(sk.names),
        "parents": list(sk.parents),
        "joint_channels": [list(c) for c in sk.channels],
        "end_parents": list(sk.end_parents),
        "skipped": [list(s) for s in skipped],
    }
    return arrays, meta


def _unpack(arrays: dict, meta: dict, key: str) -> tuple[list[Motion], list[tuple[str, str]]]:
    """Inverse of ``_pack``; ``CacheError`` when the entry belongs to other files or is inconsistent."""
    if meta.get("key") != key:
        raise CacheError("cache key does not match the corpus files")
    try:
        bounds = np.concatenate([[0], np.cumsum(arrays["lengths"])])
        if bounds[-1] != len(arrays["channels"]) or len(meta["names"]) != len(arrays["lengths"]):
            raise CacheError("cache arrays are inconsistent")
        topology = (tuple(meta["joints"]), tuple(meta["parents"]), tuple(tuple(c) for c in meta["joint_channels"]))
        motions = []
        for i, name in enumerate(meta["names"]):
            sk = Skeleton(
                names=topology[0],
                parents=topology[1],
                offsets=arrays["offsets"][i],
                channels=topology[2],
                end_sites=arrays["end_sites"][i],
                end_parents=tuple(meta["end_parents"]),
                cm_per_unit=float(arrays["cm_per_unit"][i]),
            )
            chans = arrays["channels"][bounds[i] : bounds[i + 1]]
            motions.append(Motion(sk, chans, float(arrays["fps"][i]), name))
        return motions, [(str(a), str(b)) for a, b in meta["skipped"]]
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise CacheError(f"cache entry is inconsistent ({type(exc).__name__}: {str(exc)[:80]})") from exc


def _parse_all(files: list[Path], unit: float | None, progress: bool) -> tuple[list[Motion], list[tuple[str, str]]]:
    from tqdm import tqdm

    motions: list[Motion] = []
    skipped: list[tuple[str, str]] = []
    for f in tqdm(files, desc=f"reading {files[0].parent.name}", unit="file", disable=not progress or len(files) < 20):
        try:
            motions.append(read_bvh(f, cm_per_unit=unit))
        except MocapFileError as exc:
            skipped.append((f.name, str(exc)))
    if not motions:
        raise MocapFileError(f"{files[0].parent}: no readable BVH file ({skipped[0][1] if skipped else ''})")
    topologies = Counter(m.skeleton.topology() for m in motions)
    main_topology, _ = topologies.most_common(1)[0]
    reference = next(m.skeleton for m in motions if m.skeleton.topology() == main_topology)
    kept = []
    for m in motions:
        if m.skeleton.topology() == main_topology:
            kept.append(m)
        else:
            skipped.append(
                (m.name, f"skeleton {m.skeleton.describe()} does not match the corpus skeleton {reference.describe()}")
            )
    return kept, skipped


def load_corpus(
    data: str | os.PathLike, progress: bool = True, use_cache: bool = True, limit: int | None = None
) -> Corpus:
    """Load every BVH file of a corpus (name or folder) with its folds.

    Files that fail to parse, or whose skeleton topology differs from the corpus majority, are skipped and
    reported with a warning (never mixed in). Parsed corpora are cached under ``$MOCAPNET_CACHE`` (default
    ``~/.cache/mocapnet``) as ``.npz`` (no pickle), keyed by a SHA-256 of the files' content and checked by a
    checksum; a damaged or edited cache entry is rebuilt with a warning. ``limit`` keeps the first N files by
    name (for quick runs).
    """
    name, folder, unit = resolve(data)
    files = list_bvh(folder)
    if limit is not None:
        files = files[:limit]
    key = _cache_key(files, unit) if use_cache else ""
    cache_file = cache_dir() / f"{name}-{key[:24]}.npz"
    loaded = None
    if use_cache and cache_file.exists():
        try:
            loaded = _unpack(*read_cache(cache_file), key)
        except CacheError as exc:
            warnings.warn(f"{exc}; rebuilding the parse cache of {name}", stacklevel=2)
    if loaded is None:
        loaded = _parse_all(files, unit, progress)
        if use_cache:
            write_cache(cache_file, *_pack(*loaded, key))
    motions, skipped = loaded
    for fname, reason in skipped:
        warnings.warn(f"skipped {fname}: {reason}", stacklevel=2)
    folds = load_folds(name, [m.name for m in motions])
    return Corpus(name, folder, motions, folds, list(skipped))


def write_split(corpus: str, folder: Path | None = None) -> Path:
    """Compute and save the committed split file of a named corpus (run once; the file is committed)."""
    name, folder_, _ = resolve(corpus if folder is None else folder)
    names = [clip_name(p) for p in list_bvh(folder_)]
    folds = make_folds(names)
    path = SPLITS_DIR / f"{corpus}.json"
    counts = Counter(folds.values())
    payload = {
        "corpus": corpus,
        "n_folds": N_FOLDS,
        "stratified_by": "content label from the file name",
        "fold_sizes": [counts[k] for k in range(N_FOLDS)],
        "folds": folds,
    }
    path.write_text(json.dumps(payload, indent=1, sort_keys=False) + "\n")
    return path
