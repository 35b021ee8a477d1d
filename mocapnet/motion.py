"""Core data types: a BVH ``Skeleton`` with its ``Motion`` (joint angles) and C3D-style ``Markers`` (points).

Conventions used throughout mocapnet:

* channels are a float64 array ``[T, C]`` in the file's units (degrees for rotations, skeleton length
  units for translations), rows are frames;
* points are a float64 array ``[T, M, 3]`` in centimetres, with a boolean ``visible`` array ``[T, M]``;
* a *mask* is a boolean array that is ``True`` where a sample is missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
CHANNEL_NAMES = ROTATION_CHANNELS + POSITION_CHANNELS

_HIP_NAMES = ("hip", "pelvis")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy with its channel layout.

    Attributes
    ----------
    names : joint names, parents before children (BVH order), length J.
    parents : parent index per joint, -1 for the root, length J.
    offsets : ``[J, 3]`` rest offsets from the parent, in skeleton length units.
    channels : per joint, the tuple of its channel names in file order (e.g. ``("Zrotation", "Xrotation",
        "Yrotation")``).
    end_sites : ``[E, 3]`` offsets of End Site points, with ``end_parents`` (joint index per end site).
    cm_per_unit : centimetres per skeleton length unit (1.0 for Bandai-Namco, ~5.64 for CMU cgspeed).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    end_parents: tuple[int, ...] = ()
    cm_per_unit: float = 1.0

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @cached_property
    def channel_offsets(self) -> np.ndarray:
        """Index of each joint's first channel in the ``[T, C]`` array, length J + 1."""
        return np.concatenate([[0], np.cumsum([len(c) for c in self.channels])]).astype(int)

    @property
    def n_channels(self) -> int:
        return int(self.channel_offsets[-1])

    @cached_property
    def channel_labels(self) -> tuple[str, ...]:
        """``"Joint.Xrotation"`` style label for each column of the channel array."""
        return tuple(f"{n}.{c}" for n, chans in zip(self.names, self.channels) for c in chans)

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        kids: list[list[int]] = [[] for _ in self.names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                kids[p].append(j)
        return tuple(tuple(k) for k in kids)

    @cached_property
    def context_joints(self) -> tuple[int, ...]:
        """Joints whose channels are context (clean, never corrupted or scored): the root and, when the root
        is a reference node with a single child, the chain down to the hips/pelvis joint (Bandai's
        ``joint_Root`` → ``Hips``)."""
        chain = [0]
        j = 0
        while not any(h in self.names[j].lower() for h in _HIP_NAMES) and len(self.children[j]) == 1:
            j = self.children[j][0]
            chain.append(j)
        if any(h in self.names[j].lower() for h in _HIP_NAMES):
            return tuple(chain)
        return (0,)

    def joint_channels(self, joint: int) -> np.ndarray:
        """Column indices of ``joint``'s channels."""
        return np.arange(self.channel_offsets[joint], self.channel_offsets[joint + 1])

    @cached_property
    def rotation_mask(self) -> np.ndarray:
        """Boolean ``[C]``: True for rotation channels."""
        return np.array([c.endswith("rotation") for chans in self.channels for c in chans])

    @cached_property
    def scored_mask(self) -> np.ndarray:
        """Boolean ``[C]``: rotation channels of every non-context joint (corrupted and scored)."""
        mask = self.rotation_mask.copy()
        for j in self.context_joints:
            mask[self.joint_channels(j)] = False
        return mask

    @cached_property
    def rotation_groups(self) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
        """Joints grouped by rotation axis order: ``(seq, joints [G], columns [G, len(seq)])`` per order,
        e.g. ``("ZXY", …)`` — a joint's rotation channels in file order compose as intrinsic rotations."""
        groups: dict[str, tuple[list[int], list[list[int]]]] = {}
        for j, names in enumerate(self.channels):
            rot = [(int(c), n[0]) for c, n in zip(self.joint_channels(j), names) if n.endswith("rotation")]
            if rot:
                seq = "".join(axis for _, axis in rot)
                joints, cols = groups.setdefault(seq, ([], []))
                joints.append(j)
                cols.append([c for c, _ in rot])
        return tuple((seq, np.array(j, dtype=int), np.array(c, dtype=int)) for seq, (j, c) in groups.items())

    @cached_property
    def position_channels(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position channels as ``(joint, axis 0-2, column)`` index arrays (translation of each joint)."""
        found = [
            (j, "XYZ".index(n[0]), int(c))
            for j, names in enumerate(self.channels)
            for c, n in zip(self.joint_channels(j), names)
            if n.endswith("position")
        ]
        return tuple(np.array([f[i] for f in found], dtype=int) for i in range(3))  # type: ignore[return-value]

    @cached_property
    def scored_joints(self) -> np.ndarray:
        """Indices of joints that have at least one scored channel."""
        return np.array([j for j in range(self.n_joints) if self.scored_mask[self.joint_channels(j)].any()], dtype=int)

    def topology(self) -> tuple:
        """Hashable description of names, parents and channel layout (offsets excluded): two skeletons with
        the same topology can share a corpus and a model."""
        return (self.names, self.parents, self.channels)

    def describe(self) -> str:
        """One-line description used in error messages."""
        root = self.names[0] if self.names else "?"
        return f"{self.n_joints} joints (root {root!r}), {self.n_channels} channels"


@dataclass(frozen=True, eq=False)
class Motion:
    """Joint-angle motion: ``channels [T, C]`` (degrees / skeleton units) sampled at ``fps``. A motion read from
    a file keeps what a writer needs to give it back as the file had it: ``frame_time`` (s, the file's own
    ``Frame Time``, which ``fps`` may round: 0.033333 s is 30 fps) and ``encoding`` (of its joint names)."""

    skeleton: Skeleton
    channels: np.ndarray
    fps: float
    name: str = ""
    frame_time: float | None = None
    encoding: str = "utf-8"

    def __post_init__(self) -> None:
        ch = np.asarray(self.channels, dtype=np.float64)
        if ch.ndim != 2 or ch.shape[1] != self.skeleton.n_channels:
            raise ValueError(
                f"{self.name or 'motion'}: channels have shape {ch.shape}, "
                f"skeleton has {self.skeleton.n_channels} channels"
            )
        object.__setattr__(self, "channels", ch)

    @property
    def n_frames(self) -> int:
        return self.channels.shape[0]

    @property
    def duration(self) -> float:
        """Seconds."""
        return self.n_frames / self.fps

    def with_channels(self, channels: np.ndarray) -> Motion:
        """Same skeleton, rate and name with new channel values ``[T', C]``."""
        return replace(self, channels=np.asarray(channels, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class Markers:
    """Point trajectories: ``points [T, M, 3]`` in cm and ``visible [T, M]`` (False = missing).

    Missing samples hold NaN in ``points``.
    """

    points: np.ndarray
    visible: np.ndarray
    labels: tuple[str, ...]
    fps: float
    name: str = ""

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=np.float64)
        vis = np.asarray(self.visible, dtype=bool)
        if pts.ndim != 3 or pts.shape[2] != 3:
            raise ValueError(f"{self.name or 'markers'}: points must be [T, M, 3], got {pts.shape}")
        if vis.shape != pts.shape[:2]:
            raise ValueError(f"{self.name or 'markers'}: visible {vis.shape} does not match points {pts.shape}")
        if len(self.labels) != pts.shape[1]:
            raise ValueError(f"{self.name or 'markers'}: {len(self.labels)} labels for {pts.shape[1]} points")
        pts[~vis] = np.nan
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "visible", vis)
        object.__setattr__(self, "labels", tuple(self.labels))

    @property
    def n_frames(self) -> int:
        return self.points.shape[0]

    @property
    def n_markers(self) -> int:
        return self.points.shape[1]

    def index(self, label: str) -> int:
        """Index of a marker by label (exact match, else match after a ``Subject:`` prefix)."""
        if label in self.labels:
            return self.labels.index(label)
        bare = [lab.rsplit(":", 1)[-1] for lab in self.labels]
        if label in bare:
            return bare.index(label)
        raise KeyError(f"{self.name or 'markers'}: no marker labelled {label!r}")

    def select(self, indices: np.ndarray | list[int]) -> Markers:
        idx = np.asarray(indices, dtype=int)
        return replace(
            self, points=self.points[:, idx], visible=self.visible[:, idx], labels=[self.labels[i] for i in idx]
        )
