"""Corruption synthesis (PROTOCOL.md): noise and gaps as pure functions taking ``np.random.Generator``.

Angle corruptions act on a clean ``Motion`` and return ``(noisy [T, C], mask [T, C])``: the corrupted
channels (NaN where missing) and the missing-sample mask (True = missing). Only the skeleton's scored
channels (rotations of non-context joints) are touched. ``σ_c`` is the standard deviation of channel ``c``
over the clean clip.

Point corruptions act on clean ``Markers`` and return new ``Markers`` whose ``visible`` is False where data
was removed.

A corruption name is parsed once, at the edge (CLI, configs), into a ``Corruption``; every function here
takes either the object or the name.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from mocapnet.kinematics import inverse_kinematics, joint_positions, motion_points
from mocapnet.motion import Markers, Motion
from mocapnet.segments import SEGMENTS, marker_segment, skeleton_segment

ANGLE_CORRUPTIONS = (
    "none",
    "angular-0.1",
    "angular-0.5",
    "angular-0.9",
    "spatial-0.1cm",
    "spatial-0.5cm",
    "spatial-1cm",
    "spatial-3cm",
    "spatial-ends",
    "uniform-0.5",
    "bias-const",
    "bias-sine",
    "gaps",
    "gaps-long",
    "noise+gaps",
)
POINT_CORRUPTIONS = ("segment-gap:SEG:S", "marker-gap:S")


@dataclass(frozen=True)
class Corruption:
    """A parsed corruption name (PROTOCOL.md). ``text`` is the name as written (seeds and tables use it),
    ``kind`` one of ``KINDS``, ``level`` its number (K for angular/uniform, cm for spatial, seconds for point
    gaps) and ``segment`` the body segment of a ``segment-gap``."""

    text: str
    kind: str
    level: float | None = None
    segment: str | None = None

    KINDS = ("none", "angular", "uniform", "spatial", "spatial-ends", "bias-const", "bias-sine", "gaps",
             "gaps-long", "noise+gaps", "segment-gap", "marker-gap")  # fmt: skip

    @classmethod
    def parse(cls, text: str | Corruption) -> Corruption:
        """Parse a name (a ``Corruption`` is returned as it is); ValueError listing the known names."""
        if isinstance(text, Corruption):
            return text
        text = str(text)
        if text in ("none", "spatial-ends", "bias-const", "bias-sine", "gaps", "gaps-long", "noise+gaps"):
            return cls(text, text)
        parts = text.split(":")
        if parts[0] == "segment-gap" and len(parts) == 3 and parts[1] in SEGMENTS and _number(parts[2]) is not None:
            return cls(text, "segment-gap", _number(parts[2]), parts[1])
        if parts[0] == "marker-gap" and len(parts) == 2 and _number(parts[1]) is not None:
            return cls(text, "marker-gap", _number(parts[1]))
        if parts[0] in ("segment-gap", "marker-gap"):
            raise ValueError(
                f"bad point corruption {text!r}; use segment-gap:SEG:SECONDS (SEG in {', '.join(SEGMENTS)}) "
                "or marker-gap:SECONDS"
            )
        kind, _, arg = text.partition("-")
        if kind in ("angular", "uniform") and _number(arg) is not None:
            return cls(text, kind, _number(arg))
        if kind == "spatial" and arg.endswith("cm") and _number(arg[:-2]) is not None:
            return cls(text, kind, _number(arg[:-2]))
        raise ValueError(f"unknown corruption {text!r}; known: {', '.join(ANGLE_CORRUPTIONS + POINT_CORRUPTIONS)}")

    def __str__(self) -> str:
        return self.text

    @property
    def has_gaps(self) -> bool:
        """True when it removes samples (the gap error is its headline)."""
        return self.kind in ("gaps", "gaps-long", "noise+gaps", "segment-gap", "marker-gap")

    @property
    def is_point_gap(self) -> bool:
        """``segment-gap`` / ``marker-gap``: the corruptions that also apply to C3D markers."""
        return self.kind in ("segment-gap", "marker-gap")


def check_corruption(corruption: str | Corruption) -> str:
    """The name of ``corruption`` if it is known (``Corruption.parse``), else ValueError listing the known."""
    return Corruption.parse(corruption).text


def seed_for(corpus: str, file: str, repeat: int, corruption: str | Corruption = "") -> int:
    """Deterministic seed from (corpus, file name, repeat, corruption) so every run scores the same inputs."""
    digest = hashlib.sha256(f"{corpus}|{file}|{repeat}|{corruption}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


def channel_std(channels: np.ndarray) -> np.ndarray:
    """``σ_c``: standard deviation of each channel over the clip, ``[C]``."""
    return channels.std(axis=0)


def angular_noise(
    channels: np.ndarray, scored: np.ndarray, k: float, rng: np.random.Generator, sigma: np.ndarray | None = None
) -> np.ndarray:
    """Add i.i.d. Gaussian noise of std ``k·σ_c`` to the scored channels of ``channels [T, C]``; ``sigma``
    ``[C]`` overrides ``σ_c`` (e.g. the whole clip's σ for a training crop)."""
    std = k * (channel_std(channels) if sigma is None else sigma) * scored
    return channels + rng.standard_normal(channels.shape) * std


def uniform_noise(
    channels: np.ndarray, scored: np.ndarray, k: float, rng: np.random.Generator, sigma: np.ndarray | None = None
) -> np.ndarray:
    """Add i.i.d. uniform noise with std ``k·σ_c`` (half-width ``√3·k·σ_c``) to the scored channels;
    ``sigma [C]`` overrides ``σ_c``."""
    half = np.sqrt(3.0) * k * (channel_std(channels) if sigma is None else sigma) * scored
    return channels + rng.uniform(-1.0, 1.0, channels.shape) * half


def constant_bias(
    channels: np.ndarray, scored: np.ndarray, k: float, rng: np.random.Generator, sigma: np.ndarray | None = None
) -> np.ndarray:
    """Add a constant offset of ``±k·σ_c`` (random sign per channel) to the scored channels; ``sigma``
    ``[C]`` overrides ``σ_c`` (pass the clean clip's when ``channels`` is already noisy)."""
    sign = rng.choice([-1.0, 1.0], size=channels.shape[1])
    std = channel_std(channels) if sigma is None else sigma
    return channels + sign * k * std * scored


def sine_bias(
    channels: np.ndarray,
    scored: np.ndarray,
    k: float,
    fps: float,
    rng: np.random.Generator,
    sigma: np.ndarray | None = None,
) -> np.ndarray:
    """Add ``k·σ_c·sin(2π f t + φ)`` per channel, f uniform in [0.1, 1] Hz, φ uniform in [0, 2π); ``sigma``
    ``[C]`` overrides ``σ_c``."""
    n_frames, n_ch = channels.shape
    freq = rng.uniform(0.1, 1.0, n_ch)
    phase = rng.uniform(0.0, 2 * np.pi, n_ch)
    t = np.arange(n_frames)[:, None] / fps
    std = channel_std(channels) if sigma is None else sigma
    return channels + k * std * scored * np.sin(2 * np.pi * freq * t + phase)


ADDITIVE_NOISE = ("angular-K", "uniform-K", "bias-const", "bias-sine", "noise+gaps")


def additive_noise(
    corruption: str | Corruption, channels: np.ndarray, sigma: np.ndarray, fps: float, rng: np.random.Generator
) -> np.ndarray:
    """``channels [T, C]`` with the additive angle noise of ``corruption`` (``ADDITIVE_NOISE``; for
    ``noise+gaps`` its angular-0.5 part), using per-channel ``sigma [C]`` as ``σ_c`` (0 leaves a channel
    untouched). Raises ValueError for corruptions that are not additive angle noise."""
    c = Corruption.parse(corruption)
    every = np.ones(channels.shape[1], dtype=bool)
    if c.kind == "angular":
        return angular_noise(channels, every, c.level, rng, sigma)
    if c.kind == "uniform":
        return uniform_noise(channels, every, c.level, rng, sigma)
    if c.kind == "noise+gaps":
        return angular_noise(channels, every, 0.5, rng, sigma)
    if c.kind == "bias-const":
        return constant_bias(angular_noise(channels, every, 0.5, rng, sigma), every, 0.5, rng, sigma)
    if c.kind == "bias-sine":
        return sine_bias(angular_noise(channels, every, 0.5, rng, sigma), every, 0.5, fps, rng, sigma)
    raise ValueError(f"{c.text!r} is not an additive angle noise ({', '.join(ADDITIVE_NOISE)})")


def spatial_noise(motion: Motion, std_cm: float | np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Channels after i.i.d. 3-D Gaussian noise of ``std_cm`` (scalar, or ``[J + E]`` per joint and End
    Site) on every joint position, taken back to angles by bone-length-preserving IK."""
    pos = joint_positions(motion, end_sites=True)
    std = np.broadcast_to(np.asarray(std_cm, dtype=np.float64), (pos.shape[1],))
    noisy = pos + rng.standard_normal(pos.shape) * std[None, :, None]
    return inverse_kinematics(motion, noisy)


def end_joint_std(motion: Motion, ends_cm: float = 0.5, other_cm: float = 0.1) -> np.ndarray:
    """Per-point std for ``spatial-ends``: ``ends_cm`` on wrists/hands, ankles/feet (and their End Sites
    and children), ``other_cm`` elsewhere; ``[J + E]``."""
    sk = motion.skeleton
    ends = ("hand", "wrist", "finger", "thumb", "foot", "ankle", "toe")
    is_end = [any(e in n.lower() for e in ends) for n in sk.names]
    is_end += [is_end[p] for p in sk.end_parents]
    return np.where(is_end, ends_cm, other_cm)


def _mean_gap_frames(mean_frames: float, max_frames: int) -> float:
    """Mean length of ``clip(round(Exp(mean)), 1, max)``, computed on a fixed sample."""
    sample = np.random.default_rng(0).exponential(mean_frames, 200_000)
    return float(np.clip(np.round(sample), 1, max_frames).mean())


def gap_mask(
    n_frames: int,
    n_tracks: int,
    fps: float,
    rng: np.random.Generator,
    mean_s: float = 0.5,
    max_s: float = 2.0,
    fraction: float = 0.1,
) -> np.ndarray:
    """Missing-data mask ``[T, n_tracks]`` (True = missing) of exponential-length gaps.

    Gap lengths are exponential with mean ``mean_s`` seconds, at least 1 frame and at most ``max_s``;
    onsets are Bernoulli per frame with the rate that makes about ``fraction`` of each track missing.
    No gap touches the first or last frame.
    """
    mask = np.zeros((n_frames, n_tracks), dtype=bool)
    if n_frames < 3:
        return mask
    mean_f = mean_s * fps
    max_f = max(1, int(round(max_s * fps)))
    mean_len = _mean_gap_frames(mean_f, max_f)
    p_onset = min(1.0, fraction / (mean_len * (1.0 - fraction)))
    for track in range(n_tracks):
        t = 1
        while True:
            t += int(rng.geometric(p_onset)) - 1
            if t >= n_frames - 1:
                break
            length = int(np.clip(round(rng.exponential(mean_f)), 1, max_f))
            end = min(t + length, n_frames - 1)
            mask[t:end, track] = True
            t = end + 1
    return mask


def long_gap_mask(
    n_frames: int,
    candidates: np.ndarray,
    n_tracks: int,
    fps: float,
    rng: np.random.Generator,
    min_s: float = 2.0,
    max_s: float = 5.0,
) -> np.ndarray:
    """``[T, n_tracks]`` mask with 1 to 3 random tracks (from ``candidates``) each missing one gap of
    ``min_s`` to ``max_s`` seconds (uniform), shortened to fit inside frames 1 … T-2."""
    mask = np.zeros((n_frames, n_tracks), dtype=bool)
    if n_frames < 3:
        return mask
    count = int(rng.integers(1, 4))
    for track in rng.choice(candidates, size=min(count, len(candidates)), replace=False):
        length = min(int(round(rng.uniform(min_s, max_s) * fps)), n_frames - 2)
        place_gap(mask, track, length, 1, rng)
    return mask


def place_gap(
    mask: np.ndarray, tracks: int | Sequence[int] | np.ndarray, length: int, margin: int, rng: np.random.Generator
) -> None:
    """Mark ``tracks`` of ``mask [T, n_tracks]`` missing (True, in place) for ``length`` frames at one onset
    drawn uniformly (one ``rng.integers`` draw) from ``margin … T - margin - length``, so that at least
    ``margin`` frames stay visible on each side. The caller makes sure that range is not empty."""
    onset = int(rng.integers(margin, len(mask) - margin - length + 1))
    mask[onset : onset + length, tracks] = True


def window_gap_mask(
    n_frames: int,
    tracks: list[int],
    n_tracks: int,
    seconds: float,
    fps: float,
    rng: np.random.Generator,
    margin_s: float = 1.0,
    name: str = "",
) -> np.ndarray:
    """``[T, n_tracks]`` mask with ``tracks`` all missing for ``seconds`` at one random onset, leaving at
    least ``margin_s`` seconds visible on each side. Raises ValueError when the clip is too short."""
    length = max(1, int(round(seconds * fps)))
    margin = int(round(margin_s * fps))
    last_onset = n_frames - margin - length
    if last_onset < margin:
        raise ValueError(
            f"{name or 'clip'}: {n_frames} frames at {fps:g} Hz are too short for a {seconds:g} s gap with "
            f"{margin_s:g} s visible on each side"
        )
    mask = np.zeros((n_frames, n_tracks), dtype=bool)
    place_gap(mask, tracks, length, margin, rng)
    return mask


def joint_mask_to_channels(motion: Motion, joint_mask: np.ndarray) -> np.ndarray:
    """Expand a per-joint mask ``[T, J]`` to the joints' scored channels ``[T, C]``."""
    sk = motion.skeleton
    mask = np.zeros(motion.channels.shape, dtype=bool)
    for j in range(sk.n_joints):
        cols = sk.joint_channels(j)
        cols = cols[sk.scored_mask[cols]]
        mask[:, cols] = joint_mask[:, [j]]
    return mask


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _apply_mask(channels: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = channels.copy()
    out[mask] = np.nan
    return out


def corrupt_motion(
    motion: Motion, corruption: str | Corruption, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Apply an angle corruption (``ANGLE_CORRUPTIONS``, or a point gap on the skeleton's segments) to a
    clean motion.

    Returns ``(noisy [T, C], mask [T, C])`` with NaN in ``noisy`` where ``mask`` is True.
    """
    c = Corruption.parse(corruption)
    ch = motion.channels
    scored = motion.skeleton.scored_mask
    no_gaps = np.zeros(ch.shape, dtype=bool)
    n_j = motion.skeleton.n_joints
    if c.kind == "none":
        return ch.copy(), no_gaps
    if c.kind in ("angular", "uniform", "bias-const", "bias-sine"):
        return additive_noise(c, ch, channel_std(ch) * scored, motion.fps, rng), no_gaps
    if c.kind == "spatial-ends":
        return spatial_noise(motion, end_joint_std(motion), rng), no_gaps
    if c.kind == "spatial":
        return spatial_noise(motion, c.level, rng), no_gaps
    if c.kind == "gaps":
        mask = joint_mask_to_channels(motion, gap_mask(motion.n_frames, n_j, motion.fps, rng))
        return _apply_mask(ch, mask), mask
    if c.kind == "gaps-long":
        joints = motion.skeleton.scored_joints
        mask = joint_mask_to_channels(motion, long_gap_mask(motion.n_frames, joints, n_j, motion.fps, rng))
        return _apply_mask(ch, mask), mask
    if c.kind == "noise+gaps":
        noisy = angular_noise(ch, scored, 0.5, rng)
        mask = joint_mask_to_channels(motion, gap_mask(motion.n_frames, n_j, motion.fps, rng))
        return _apply_mask(noisy, mask), mask
    joint_mask = point_gap_mask(
        c,
        motion.n_frames,
        motion.fps,
        rng,
        lambda seg: skeleton_segment(motion.skeleton, seg),
        n_j,
        list(motion.skeleton.scored_joints),
        motion.name,
    )
    mask = joint_mask_to_channels(motion, joint_mask)
    return _apply_mask(ch, mask), mask


def point_gap_mask(
    corruption: str | Corruption,
    n_frames: int,
    fps: float,
    rng: np.random.Generator,
    segment_tracks: Callable[[str], list[int]],
    n_tracks: int,
    candidates: list[int],
    name: str = "",
) -> np.ndarray:
    """Mask ``[T, n_tracks]`` for ``segment-gap:SEG:S`` or ``marker-gap:S``.

    ``segment_tracks(seg)`` gives the track indices of a segment; ``candidates`` the tracks a single
    marker gap may pick from.
    """
    c = Corruption.parse(corruption)
    if not c.is_point_gap:
        raise ValueError(f"{c.text!r} is not a point gap; use segment-gap:SEG:SECONDS or marker-gap:SECONDS")
    tracks = segment_tracks(c.segment) if c.kind == "segment-gap" else [int(rng.choice(candidates))]
    return window_gap_mask(n_frames, tracks, n_tracks, c.level, fps, rng, name=name)


def corrupt_markers(markers: Markers, corruption: str | Corruption, rng: np.random.Generator) -> Markers:
    """Remove data from clean markers by a point corruption; returns Markers with ``visible`` reduced."""
    candidates = list(np.flatnonzero(markers.visible.all(axis=0)))
    mask = point_gap_mask(
        corruption,
        markers.n_frames,
        markers.fps,
        rng,
        lambda seg: marker_segment(markers.labels, seg),
        markers.n_markers,
        candidates,
        markers.name,
    )
    return Markers(markers.points, markers.visible & ~mask, markers.labels, markers.fps, markers.name)


def motion_markers(motion: Motion, channels: np.ndarray | None = None) -> Markers:
    """Joint positions of a motion as ``Markers`` (one point per joint, labelled by joint name, cm):
    ``kinematics.motion_points`` without End Sites."""
    return motion_points(motion, channels, end_sites=False)
