"""The motion database of the joint-space kNN gap filler (``mocapnet.methods.knn_angles``).

For a skeleton, the default database is the largest corpus of that skeleton topology under the data root
(bandai2 for the Bandai-Namco skeleton). Every frame is stored twice:

* ``channels [N, S]`` float32: the scored rotation channels (degrees, unwrapped along each clip), what a
  fill copies;
* ``points [N, P, 3]`` float32: joint and End Site positions (cm) normalised for bone lengths (forward
  kinematics of the frame's angles on one *reference* skeleton: the first clip's offsets and the corpus's
  median non-context translation channels), root position and heading (``knn.body_frames``: origin at the
  hips, heading from the left to the right up-leg joint, ``up`` the database's up axis), what a search
  compares.

A built database is cached as ``$MOCAPNET_CACHE/knn-<corpus>-<key>.npz`` (``np.savez``, read with
``allow_pickle=False``: data, never code). ``key`` is a SHA-256 of the format version and the bytes of
every source file, so a changed corpus gets a new entry. The file also holds a SHA-256 checksum of its
arrays; an entry whose checksum does not match (or that cannot be read) is rebuilt with a warning.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mocapnet.corpus import CORPORA, cache_dir, data_root, list_bvh, load_corpus
from mocapnet.kinematics import joint_positions, point_labels
from mocapnet.methods.knn import body_frames, detect_anchors, normalise, up_axis
from mocapnet.motion import Motion, Skeleton
from mocapnet.safe_cache import CacheError, content_hash, read_cache, write_cache

FORMAT_VERSION = 2
_ARRAYS = ("channels", "points", "clip", "names", "translations", "offsets", "end_sites", "labels", "up", "fps")


def translation_columns(skeleton: Skeleton) -> np.ndarray:
    """Channel columns ``[K]`` of the position channels of non-context joints (bone lengths on Bandai)."""
    context = set(skeleton.context_joints)
    return np.array(
        [
            c
            for j in range(skeleton.n_joints)
            if j not in context
            for c, name in zip(skeleton.joint_channels(j), skeleton.channels[j])
            if name.endswith("position")
        ],
        dtype=int,
    )


@dataclass(frozen=True)
class Reference:
    """The reference skeleton every pose is measured on: offsets ``[J, 3]`` and End Sites ``[E, 3]`` (units of
    the skeleton), non-context translation channel values ``[C]`` (NaN elsewhere), up axis (0, 1, 2)."""

    offsets: np.ndarray
    end_sites: np.ndarray
    translations: np.ndarray
    up: int

    def points(self, skeleton: Skeleton, channels: np.ndarray, fps: float, name: str = "") -> np.ndarray:
        """Normalised positions ``[T, P, 3]`` (cm) of ``channels [T, C]`` (no NaN) on the reference skeleton."""
        ch = channels.copy()
        cols = translation_columns(skeleton)
        ch[:, cols] = self.translations[cols]
        ref = replace(skeleton, offsets=self.offsets, end_sites=self.end_sites)
        pts = joint_positions(Motion(ref, ch, fps, name), end_sites=True)
        labels = point_labels(skeleton)
        visible = np.ones(pts.shape[:2], dtype=bool)
        origin, rot = body_frames(pts, visible, labels, detect_anchors(labels), self.up, name)
        return normalise(pts, origin, rot)


@dataclass
class SkeletonDatabase:
    """Clean frames of one skeleton topology (module docstring): ``channels [N, S]`` (scored rotation
    channels, degrees), ``points [N, P, 3]`` (cm), ``clip [N]`` (index into ``names``), rate ``fps``."""

    channels: np.ndarray
    points: np.ndarray
    clip: np.ndarray
    names: tuple[str, ...]
    labels: tuple[str, ...]
    reference: Reference
    fps: float
    source: str = ""

    @classmethod
    def from_motions(cls, motions: Sequence[Motion], source: str = "") -> SkeletonDatabase:
        """Build from clean motions of one topology (the first one's skeleton is the reference)."""
        if not motions:
            raise ValueError("knn: the database is empty (no clean clip given)")
        sk = motions[0].skeleton
        for m in motions:
            if m.skeleton.topology() != sk.topology():
                raise ValueError(
                    f"knn database {source}: {m.name} has skeleton {m.skeleton.describe()}, not {sk.describe()}"
                )
        cols = translation_columns(sk)
        translations = np.full(sk.n_channels, np.nan)
        if cols.size:
            translations[cols] = np.median(np.concatenate([m.channels[:1, cols] for m in motions]), axis=0)
        probe = [joint_positions(m, end_sites=True) for m in motions[:: max(1, len(motions) // 50)]]
        up = up_axis(np.concatenate(probe))
        ref = Reference(sk.offsets.copy(), sk.end_sites.copy(), translations, up)
        scored = sk.scored_mask
        chans = np.concatenate([m.channels[:, scored] for m in motions]).astype(np.float32)
        points = np.concatenate([ref.points(m.skeleton, m.channels, m.fps, m.name) for m in motions]).astype(np.float32)
        clip = np.concatenate([np.full(m.n_frames, i, dtype=np.int32) for i, m in enumerate(motions)])
        fps = float(motions[0].fps)
        names = tuple(m.name for m in motions)
        return cls(chans, points, clip, names, tuple(point_labels(sk)), ref, fps, source)

    def _arrays(self) -> dict[str, np.ndarray]:
        ref = self.reference
        return {
            "channels": self.channels,
            "points": self.points,
            "clip": self.clip,
            "names": np.array(self.names, dtype=str),
            "labels": np.array(self.labels, dtype=str),
            "translations": ref.translations,
            "offsets": ref.offsets,
            "end_sites": ref.end_sites,
            "up": np.array(ref.up),
            "fps": np.array(self.fps),
        }

    def save(self, path: Path) -> None:
        """Write an ``.npz`` (no pickled objects) with a checksum, atomically (``mocapnet.safe_cache``); a cache
        folder that cannot be written only costs a warning."""
        write_cache(path, self._arrays(), {"source": self.source})

    @classmethod
    def load(cls, path: Path) -> SkeletonDatabase:
        """Read a database written by ``save``. Raises ValueError naming the file when it cannot be read or
        its checksum does not match its arrays (a damaged or tampered entry)."""
        stored, meta = read_cache(path)
        missing = [k for k in _ARRAYS if k not in stored]
        if missing or not isinstance(meta.get("source"), str):
            raise CacheError(f"{path}: not a knn database (missing {missing or ['source']})")
        arrays, source = {k: stored[k] for k in _ARRAYS}, meta["source"]
        ref = Reference(arrays["offsets"], arrays["end_sites"], arrays["translations"], int(arrays["up"]))
        return cls(
            arrays["channels"],
            arrays["points"],
            arrays["clip"],
            tuple(str(n) for n in arrays["names"]),
            tuple(str(n) for n in arrays["labels"]),
            ref,
            float(arrays["fps"]),
            source,
        )

    def check(self, skeleton: Skeleton, name: str = "") -> None:
        """Raise ValueError naming ``name`` when ``skeleton``'s points differ from the database's."""
        if tuple(point_labels(skeleton)) != self.labels:
            raise ValueError(
                f"{name or 'motion'}: skeleton {skeleton.describe()} does not match the knn database "
                f"{self.source or ''} ({len(self.labels)} points: {list(self.labels[:4])}…)"
            )

    def describe(self) -> str:
        return f"{self.source or 'database'}: {len(self.names)} clips, {len(self.clip)} frames"


def content_key(files: Sequence[Path]) -> str:
    """SHA-256 (24 hex digits) of the format version and the names and bytes of ``files``."""
    return content_hash(files, salt=f"knn-db-v{FORMAT_VERSION}")[:24]


def cached_database(corpus: str, motions: Sequence[Motion] | None = None) -> SkeletonDatabase:
    """The database of a corpus (name or folder), from the cache when its content key matches, else built
    (from ``motions`` when given, else ``load_corpus``) and cached. A cache entry that fails its checksum is
    rebuilt with a warning."""
    from mocapnet.corpus import resolve

    name, folder, _ = resolve(corpus)
    path = cache_dir() / f"knn-{name}-{content_key(list_bvh(folder))}.npz"
    if path.exists():
        try:
            return SkeletonDatabase.load(path)
        except ValueError as exc:
            warnings.warn(f"knn: rebuilding the database cache: {exc}", stacklevel=2)
    clips = list(motions) if motions is not None else load_corpus(corpus, progress=False).motions
    db = SkeletonDatabase.from_motions(clips, source=name)
    db.save(path)
    return db


def default_corpus(skeleton: Skeleton) -> str | None:
    """Name of the largest corpus under the data root whose skeleton has ``skeleton``'s topology (None if
    none): compares the first file of each known corpus."""
    from mocapnet.io.bvh import read_bvh

    best: tuple[int, str] | None = None
    for name, (sub, unit) in CORPORA.items():
        folder = data_root() / sub
        if not folder.is_dir():
            continue
        files = list_bvh(folder)
        if read_bvh(files[0], cm_per_unit=unit).skeleton.topology() == skeleton.topology():
            if best is None or len(files) > best[0]:
                best = (len(files), name)
    return best[1] if best else None
