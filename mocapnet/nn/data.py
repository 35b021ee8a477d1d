"""LightningDataModule for the cleaners: clips in memory, random fixed-length crops corrupted afresh for every
training window, and a fixed corrupted validation set.

Splits. A corpus of many clips uses its committed 5-fold split (``Corpus.split(fold)``: train = three folds,
validation = fold k+1, test = fold k). A corpus of a single clip (``cmu120``, ``sample``) is split in time:
the first ``time_split[0]`` of its frames train, the next ``time_split[1]`` validate, the rest test
(default 70 % / 15 % / 15 %, see ``mocapnet.corpus.time_segments``).

Training batches. Each batch draws one crop length ``L`` (with probability ``window_fraction`` exactly
``window_frames``, the length one windowed-mode window covers; otherwise uniform in ``[crop_min, crop_max]``),
then ``batch_size`` crops of ``L`` frames, uniformly over every valid crop position of the clips at least
``L`` long. Each crop gets a corruption drawn from ``corruptions`` with fresh noise and gap layout. Noise
uses the standard deviation σ_c of the whole (training) clip, as PROTOCOL.md defines it for test clips,
not of the crop. Random streams are seeded by ``(seed, rank, epoch counter)``; the counter is saved in the
checkpoint, so a resumed run draws the batches an uninterrupted run would.

Worker processes (``num_workers=N > 0``, for a GPU that one process cannot keep busy): the epoch's batches are
shared out among N DataLoader workers, worker k drawing its own from ``(seed, rank, epoch counter, N, k)``;
the loader takes them in turn, so a run is as reproducible (and resumable) as with ``num_workers=0`` for the
same N, but draws other batches than another N.

Spatial noise (``spatial-Xcm``) on a crop: IK per crop is too slow for training, so ``setup`` computes, once per
training clip and level X, the angle change that X cm of 3-D joint noise causes through bone-length-preserving
IK (``corrupt.spatial_noise``); a crop adds that residual at its (nearest, when time-warped) frames with a random sign.

Time warping (``time_warp=(lo, hi)``): each batch is resampled at a rate drawn log-uniformly in ``[lo, hi]``
(linear interpolation of the unwrapped channels; the root angular velocity is scaled by the rate), so the
networks see motions played faster and slower than recorded. A random root heading is not needed: the only
root input, the hips' angular velocity, is expressed in the hips' own frame.

Mirroring (``mirror=True``): every training clip is joined by its left/right mirror image (``mocapnet.mirror``:
the skeleton's per-joint frame reflections are fitted once to the training clips, so rigs whose joint frames
differ joint to joint, as Bandai's do, mirror exactly), doubling the training motion; validation is unchanged.

Limb mixing (``limb_mix=P``): with probability P a training crop takes the channels of one limb (``GAP_SEGMENTS``)
from a crop of another training clip (its own mirror image can be; itself only when no other clip is long
enough), at the same length and time-warp
rate, with that clip's σ_c, clip statistics and spatial-noise residual for those channels; so the networks meet
combinations of the training contents that no recording holds (an arm from one content on the body of another),
meant to make a content they never saw less new. The spliced spatial residual is approximate: the joints next to
the limb were solved against the first clip's limb noise. Off (0) by default. ``limb_mix_corruptions`` (names
from ``corruptions``) restricts it to the crops drawn with those corruptions, e.g. the whole-limb gaps only
(None, the default: every crop).

Gaps are interpolated before a network sees them (``fill.gap_fill``): by cubic spline for gaps of at most
``spline_max_s`` seconds, linearly beyond (0, the default: linearly everywhere). An EBD trained so must be built
with the same ``spline_max_s``, since it predicts a correction to that interpolation.

Validation clips are corrupted once with ``corrupt_motion`` and the protocol's seeds (repeat 0).

Clip statistics (``base.NORM_KEYS``, used by ``norm="clip"`` and ``"both"`` networks). A validation clip
carries those of its whole noisy input (``base.clip_statistics``), as inference computes them. A training crop
carries those its whole clip would have with the crop's noise (``crop_statistics``): the clean clip's circular
centre shifted by the crop's mean noise, the clean clip's variance plus the crop's noise variance, the clean
clip's angular velocity RMS times the time-warp rate; so a crop of 31 frames is normalised as the whole clip
would be (with limb mixing, the limb's channels as their own clip would be).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from typing import Any

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset

from mocapnet.corpus import load_corpus
from mocapnet.corrupt import (
    additive_noise,
    corrupt_motion,
    gap_mask,
    long_gap_mask,
    place_gap,
    seed_for,
    spatial_noise,
)
from mocapnet.fill import gap_fill
from mocapnet.kinematics import wrap_deg
from mocapnet.mirror import fit_mirror, mirror_motion
from mocapnet.motion import Motion, Skeleton
from mocapnet.nn.base import clip_statistics
from mocapnet.nn.features import (
    MIN_SCALE_DEG,
    ClipArrays,
    Normaliser,
    scored_index,
    scored_joint_of_channel,
    topology_hash,
)
from mocapnet.segments import skeleton_segment

TRAIN_CORRUPTIONS = (
    "none",
    "angular-K",
    "uniform-K",
    "spatial-Xcm",
    "bias-const",
    "bias-sine",
    "gaps",
    "gaps-long",
    "noise+gaps",
    "segment-gaps",
    "noise+segment-gaps",
)
#: Limbs whose scored joints ``segment-gaps`` removes together (``segments.skeleton_segment``).
GAP_SEGMENTS = ("left-arm", "right-arm", "left-leg", "right-leg")


def spatial_level(name: str) -> float | None:
    """The noise level X (cm) of a ``spatial-Xcm`` training corruption, else None."""
    if not (name.startswith("spatial-") and name.endswith("cm")):
        return None
    try:
        return float(name[len("spatial-") : -2])
    except ValueError:
        return None


def corpus_splits(
    corpus: str,
    fold: int,
    time_split: Sequence[float] = (0.7, 0.15),
    limit: int | None = None,
    holdout_style: str | None = None,
    holdout_content: str | None = None,
) -> tuple[list[Motion], list[Motion], list[Motion]]:
    """``(train, val, test)`` lists of Motion for a corpus: its fold split (without the clips of
    ``holdout_style`` or ``holdout_content``, for the unseen-style and unseen-content checks), or the time split of
    its only clip (``mocapnet.corpus.Corpus.split``)."""
    corpus_ = load_corpus(corpus, progress=False, limit=limit)
    return corpus_.split(fold, holdout_style, (time_split[0], time_split[1]), holdout_content)


def corrupt_window(
    crop: np.ndarray,
    sigma: np.ndarray,
    joint_of_channel: np.ndarray,
    fps: float,
    name: str,
    rng: np.random.Generator,
    spatial: np.ndarray | None = None,
    segments: Sequence[np.ndarray] = (),
) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt a training crop of scored channels ``[L, C_s]`` (degrees) with the training corruption
    ``name`` (one of ``TRAIN_CORRUPTIONS``, K and X numbers); ``sigma [C_s]`` is the clip's σ_c and
    ``joint_of_channel [C_s]`` maps channels to scored joints for gaps; ``spatial [L, C_s]`` (degrees) is the
    IK residual of X cm joint noise over the crop (``spatial_residual``), needed by ``spatial-Xcm``;
    ``segments`` (scored-joint indices of each limb) are needed by ``segment-gaps`` (``segment_gap_mask``;
    ``noise+segment-gaps`` adds the angular-0.5 noise of ``noise+gaps``). Returns ``(noisy, mask)``, ``noisy``
    holding the corrupted (not yet filled) values where the mask is True."""
    level = spatial_level(name)
    known = name in TRAIN_CORRUPTIONS or name.startswith(("angular-", "uniform-")) or level is not None
    if not known:
        raise ValueError(f"training corruption {name!r} is not supported; use one of {', '.join(TRAIN_CORRUPTIONS)}")
    n_joints = int(joint_of_channel.max()) + 1
    no_gaps = np.zeros(crop.shape, dtype=bool)
    if level is not None:
        if spatial is None:
            raise ValueError(f"training corruption {name!r} needs the clip's IK residual (spatial_residual)")
        return crop + rng.choice([-1.0, 1.0]) * spatial, no_gaps
    if name == "none":
        return crop.copy(), no_gaps
    if name in ("gaps", "gaps-long", "segment-gaps"):
        noisy = crop.copy()
    else:
        noisy = additive_noise("noise+gaps" if name == "noise+segment-gaps" else name, crop, sigma, fps, rng)
    if name.endswith("segment-gaps"):
        if not segments:
            raise ValueError(f"training corruption {name!r} needs the skeleton's limbs (segments)")
        joint_mask = segment_gap_mask(len(crop), segments, n_joints, fps, rng)
    elif name in ("gaps", "noise+gaps"):
        joint_mask = gap_mask(len(crop), n_joints, fps, rng)
    elif name == "gaps-long":
        joint_mask = long_gap_mask(len(crop), np.arange(n_joints), n_joints, fps, rng)
    else:
        return noisy, no_gaps
    return noisy, joint_mask[:, joint_of_channel]


def segment_gap_mask(
    n_frames: int,
    segments: Sequence[np.ndarray],
    n_joints: int,
    fps: float,
    rng: np.random.Generator,
    seconds: tuple[float, float] = (0.1, 5.0),
) -> np.ndarray:
    """Joint mask ``[L, J_s]``: every joint of one random limb (``segments``: scored-joint indices per limb)
    missing for one run of uniform length in ``seconds``, shortened to leave a visible frame at each end."""
    mask = np.zeros((n_frames, n_joints), dtype=bool)
    if n_frames < 3:
        return mask
    limb = segments[int(rng.integers(len(segments)))]
    length = int(np.clip(round(rng.uniform(*seconds) * fps), 1, n_frames - 2))
    place_gap(mask, limb, length, 1, rng)
    return mask


def limb_joints(skeleton: Skeleton) -> list[np.ndarray]:
    """Scored-joint indices (0 … J_s-1) of each limb of ``GAP_SEGMENTS`` the skeleton has."""
    scored = list(skeleton.scored_joints)
    out = []
    for segment in GAP_SEGMENTS:
        try:
            joints = skeleton_segment(skeleton, segment)
        except ValueError:
            continue
        idx = [scored.index(j) for j in joints if j in scored]
        if idx:
            out.append(np.array(idx))
    return out


def resample(x: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Rows of ``x [T, D]`` at fractional frame ``positions [L]`` (0 ≤ p ≤ T-1), linearly interpolated."""
    i0 = np.minimum(np.floor(positions).astype(np.int64), len(x) - 1)
    i1 = np.minimum(i0 + 1, len(x) - 1)
    frac = (positions - i0)[:, None]
    return (1.0 - frac) * x[i0] + frac * x[i1]


def spatial_residual(motion: Motion, level_cm: float, rng: np.random.Generator) -> np.ndarray:
    """Scored-channel change ``[T, C_s]`` (degrees, wrapped to ±180) that ``level_cm`` of i.i.d. 3-D noise on
    every joint position causes through IK (``corrupt.spatial_noise``)."""
    idx = scored_index(motion.skeleton)
    diff = spatial_noise(motion, level_cm, rng)[:, idx] - motion.channels[:, idx]
    return wrap_deg(diff).astype(np.float32)


def as_batch(
    filled: np.ndarray,
    mask: np.ndarray,
    clean: np.ndarray,
    angvel: np.ndarray,
    stats: dict[str, np.ndarray] | None = None,
) -> dict[str, torch.Tensor]:
    """Arrays ``[B, T, ·]`` → the batch dict the modules take (float32 tensors, bool mask); ``stats``: the
    clips' statistics (``base.NORM_KEYS``, ``[B, 1, ·]``), else those of the whole given ``filled`` and
    ``angvel`` (``base.clip_statistics``)."""
    batch = {
        "filled": torch.as_tensor(filled, dtype=torch.float32),
        "mask": torch.as_tensor(mask, dtype=torch.bool),
        "clean": torch.as_tensor(clean, dtype=torch.float32),
        "angvel": torch.as_tensor(angvel, dtype=torch.float32),
    }
    if stats is None:
        return batch | clip_statistics(batch["filled"], batch["angvel"])
    return batch | {k: torch.as_tensor(v, dtype=torch.float32) for k, v in stats.items()}


def crop_statistics(clip: Normaliser, clean: np.ndarray, noisy: np.ndarray, rate: float) -> dict[str, np.ndarray]:
    """Statistics (``base.NORM_KEYS``, ``[1, ·]``) that a whole clip would show with a training crop's noise
    (module docstring): ``clip`` the clean clip's own ``Normaliser``, ``clean`` / ``noisy`` the crop ``[L, C_s]``
    (degrees), ``rate`` its time-warp rate."""
    noise = wrap_deg(noisy - clean)
    scale = np.maximum(np.sqrt(clip.scale**2 + noise.var(0)), MIN_SCALE_DEG)
    return {
        "center": (clip.center + noise.mean(0))[None],
        "scale": scale[None],
        "angvel_scale": (clip.angvel_scale * rate)[None],
    }


class CropStream(IterableDataset):
    """``steps_per_epoch`` training batches per epoch (module docstring), drawn for epoch ``epoch`` (set by
    ``EpochLoader`` in the main process before any worker starts); in a DataLoader worker, that worker's share."""

    def __init__(self, module: MotionDataModule, rank: int) -> None:
        self.module = module
        self.rank = rank
        self.epoch = 0

    def __len__(self) -> int:
        return self.module.hparams.steps_per_epoch

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        dm, steps = self.module, self.module.hparams.steps_per_epoch
        worker = torch.utils.data.get_worker_info()
        if worker is None:
            rng = np.random.default_rng([dm.hparams.seed, self.rank, self.epoch])
        else:
            rng = np.random.default_rng([dm.hparams.seed, self.rank, self.epoch, worker.num_workers, worker.id])
            steps = steps // worker.num_workers + (worker.id < steps % worker.num_workers)
        for _ in range(steps):
            yield dm.sample_batch(rng)


class EpochLoader(DataLoader):
    """The training DataLoader: an epoch's iteration, at its first batch, hands the data module's epoch counter
    to the ``CropStream`` and advances it, in the main process, before the workers are started. (At the first
    batch, not when the iterator is made: Lightning may make one it never reads, e.g. with
    ``reload_dataloaders_every_n_epochs``.)"""

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        stream, dm = self.dataset, self.dataset.module
        stream.epoch = dm.epoch_counter
        dm.epoch_counter += 1
        yield from super().__iter__()


def check_limb_mix_corruptions(names: Sequence[str], corruptions: Sequence[str], limb_mix: float) -> None:
    """ValueError unless ``names`` (``limb_mix_corruptions``) is a non-empty list of names from the training
    ``corruptions``, given with a ``limb_mix`` above 0 (a list with mixing off would do nothing)."""
    training = ", ".join(dict.fromkeys(corruptions))
    if isinstance(names, str):
        raise ValueError(f"limb_mix_corruptions must be a list of names, e.g. '[{names}]'; got the string {names!r}")
    if not names:
        raise ValueError(
            f"limb_mix_corruptions is empty; give names from the training corruptions ({training}), "
            "or null for every crop"
        )
    unknown = sorted(set(names) - set(corruptions))
    if unknown:
        raise ValueError(f"limb_mix_corruptions: {', '.join(unknown)} not among the training corruptions ({training})")
    if not limb_mix:
        raise ValueError("limb_mix_corruptions is set but limb_mix is 0 (no crop is mixed); set limb_mix above 0")


class MotionDataModule(L.LightningDataModule):
    """Splits, training crops and validation clips of one corpus (module docstring).

    After ``setup()``: ``n_channels`` (scored channels), ``skeleton_hash``, ``fps``, ``normaliser()``.
    """

    def __init__(
        self,
        corpus: str = "bandai2",
        fold: int = 0,
        time_split: tuple[float, float] = (0.7, 0.15),
        corruptions: tuple[str, ...] = ("angular-0.5",),
        val_corruptions: tuple[str, ...] = ("angular-0.5",),
        batch_size: int = 32,
        crop_min: int = 64,
        crop_max: int = 128,
        window_frames: int = 31,
        window_fraction: float = 0.25,
        steps_per_epoch: int = 200,
        val_limit: int | None = None,
        limit: int | None = None,
        seed: int = 0,
        holdout_style: str | None = None,
        time_warp: tuple[float, float] | None = None,
        spline_max_s: float = 0.0,
        mirror: bool = False,
        num_workers: int = 0,
        holdout_content: str | None = None,
        limb_mix: float = 0.0,
        limb_mix_corruptions: tuple[str, ...] | None = None,
    ) -> None:
        super().__init__()
        if isinstance(num_workers, bool) or not isinstance(num_workers, int) or num_workers < 0:
            raise ValueError(f"num_workers must be a whole number >= 0, got {num_workers!r}")
        if isinstance(limb_mix, bool) or not isinstance(limb_mix, (int, float)) or not 0.0 <= limb_mix <= 1.0:
            raise ValueError(f"limb_mix must be a probability in [0, 1], got {limb_mix!r}")
        if limb_mix_corruptions is not None:
            check_limb_mix_corruptions(limb_mix_corruptions, corruptions, limb_mix)
        self.save_hyperparameters()
        self.spatial: dict[float, list[np.ndarray]] = {}
        self.epoch_counter = 0
        self.train_clips: list[ClipArrays] = []
        self.val_batches: list[dict[str, torch.Tensor]] = []

    @property
    def rank(self) -> int:
        return self.trainer.global_rank if self.trainer is not None else 0

    def setup(self, stage: str | None = None) -> None:
        if self.train_clips:
            return
        hp = self.hparams
        train, val, _ = corpus_splits(hp.corpus, hp.fold, hp.time_split, hp.limit, hp.holdout_style, hp.holdout_content)
        if not train or not val:
            raise ValueError(f"corpus {hp.corpus!r} fold {hp.fold}: empty training or validation split")
        if hp.mirror:
            mirror = fit_mirror(train)
            train = train + [mirror_motion(m, mirror) for m in train]
        skeleton = train[0].skeleton
        if hp.limb_mix and not limb_joints(skeleton):
            raise ValueError(f"limb_mix needs limbs ({', '.join(GAP_SEGMENTS)}); {skeleton.describe()} has none")
        self.skeleton_hash = topology_hash(skeleton)
        self.fps = float(train[0].fps)
        self.n_channels = int(skeleton.scored_mask.sum())
        self.channel_labels = [skeleton.channel_labels[i] for i in scored_index(skeleton)]
        self.joint_of_channel = scored_joint_of_channel(skeleton)
        self.segments = limb_joints(skeleton)
        self.train_clips = [ClipArrays.from_motion(m) for m in train]
        self.clip_norms = [Normaliser.fit([c.scored], [c.angvel]) for c in self.train_clips]
        rng = np.random.default_rng([hp.seed, 7])
        for level in sorted({spatial_level(c) for c in hp.corruptions} - {None}):
            self.spatial[level] = [spatial_residual(m, level, rng) for m in train]
        self.lengths = np.array([c.scored.shape[0] for c in self.train_clips])
        val = val[:: max(1, len(val) // hp.val_limit)][: hp.val_limit] if hp.val_limit else val
        self.val_batches = [b for m in val for c in hp.val_corruptions if (b := self.corrupted_clip(m, c))]

    def normaliser(self) -> Normaliser:
        """Input statistics of the clean training clips."""
        return Normaliser.fit([c.scored for c in self.train_clips], [c.angvel for c in self.train_clips])

    def corrupted_clip(self, motion: Motion, corruption: str, repeat: int = 0) -> dict[str, torch.Tensor] | None:
        """One whole clip as a batch of 1, corrupted with the protocol's seed for ``repeat``; None when the clip
        is too short for the corruption (e.g. a 2 s segment gap with 1 s visible each side)."""
        rng = np.random.default_rng(seed_for(self.hparams.corpus, motion.name, repeat, corruption))
        try:
            noisy, mask = corrupt_motion(motion, corruption, rng)
        except ValueError:
            return None
        idx = scored_index(motion.skeleton)
        clip = ClipArrays.from_motion(motion)
        filled = gap_fill(noisy, mask, self.hparams.spline_max_s * motion.fps)[:, idx]
        return as_batch(filled[None], mask[None][..., idx], clip.scored[None], clip.angvel[None])

    def sample_batch(self, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        """One training batch (module docstring)."""
        hp = self.hparams
        if rng.random() < hp.window_fraction:
            length = hp.window_frames
        else:
            length = int(rng.integers(hp.crop_min, hp.crop_max + 1))
        rate = float(np.exp(rng.uniform(*np.log(hp.time_warp)))) if hp.time_warp else 1.0
        longest = int(self.lengths.max())
        rate = min(rate, (longest - 1) / max(length - 1, 1))
        length = min(length, longest)
        need = int(np.ceil((length - 1) * rate)) + 1
        spans = np.maximum(self.lengths - need + 1, 0).astype(np.float64)
        clips = rng.choice(len(self.train_clips), size=hp.batch_size, p=spans / spans.sum())
        offsets = np.arange(length) * rate
        keys = ("filled", "mask", "clean", "angvel")
        out: dict[str, list[np.ndarray]] = {k: [] for k in keys}
        stats: list[dict[str, np.ndarray]] = []
        for i in clips:
            clip = self.train_clips[i]
            positions = self.crop_positions(i, spans, offsets, rng)
            clean = resample(clip.scored.astype(np.float64), positions)
            corruption = hp.corruptions[int(rng.integers(len(hp.corruptions)))]
            level = spatial_level(corruption)
            spatial = None if level is None else self.spatial[level][i][np.round(positions).astype(np.int64)]
            sigma, norm = clip.sigma, self.clip_norms[i]
            mixable = hp.limb_mix_corruptions is None or corruption in hp.limb_mix_corruptions
            if hp.limb_mix and mixable and rng.random() < hp.limb_mix:
                mixed = self.limb_from_another_clip(i, clean, sigma, norm, spatial, level, spans, offsets, rng)
                clean, sigma, norm, spatial = mixed
            args = (sigma, self.joint_of_channel, clip.fps, corruption, rng, spatial, self.segments)
            noisy, mask = corrupt_window(clean, *args)
            out["filled"].append(gap_fill(noisy, mask, hp.spline_max_s * clip.fps) if mask.any() else noisy)
            out["mask"].append(mask)
            out["clean"].append(clean)
            out["angvel"].append(resample(clip.angvel, positions) * rate)
            stats.append(crop_statistics(norm, clean, out["filled"][-1], rate))
        crop_stats = {k: np.stack([s[k] for s in stats]) for k in stats[0]}
        return as_batch(*(np.stack(out[k]) for k in keys), crop_stats)

    def crop_positions(self, clip: int, spans: np.ndarray, offsets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Fractional frames ``[L]`` of a crop of training clip ``clip``: a random start below ``spans[clip]``
        plus ``offsets`` (the time-warped frame steps), held inside the clip."""
        start = int(rng.integers(0, spans[clip]))
        return np.minimum(start + offsets, len(self.train_clips[clip].scored) - 1)

    def limb_from_another_clip(
        self,
        own: int,
        crop: np.ndarray,
        sigma: np.ndarray,
        norm: Normaliser,
        spatial: np.ndarray | None,
        level: float | None,
        spans: np.ndarray,
        offsets: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray, Normaliser, np.ndarray | None]:
        """Limb mixing (module docstring): the clean ``crop [L, C_s]`` (degrees) of training clip ``own`` with one
        random limb's channels taken from a crop of another training clip (drawn as ``sample_batch`` draws, by
        ``spans``, at frames ``start + offsets``; ``own`` itself only when no other clip is long enough), and its
        ``sigma [C_s]``, clip ``norm`` and ``spatial [L, C_s]`` residual (level ``level``) likewise. New arrays; the
        inputs are not changed."""
        weights = spans.copy()
        if weights.sum() > weights[own]:
            weights[own] = 0.0
        j = int(rng.choice(len(self.train_clips), p=weights / weights.sum()))
        other = self.train_clips[j]
        positions = self.crop_positions(j, spans, offsets, rng)
        cols = np.isin(self.joint_of_channel, self.segments[int(rng.integers(len(self.segments)))])
        crop = crop.copy()
        crop[:, cols] = resample(other.scored[:, cols].astype(np.float64), positions)
        theirs = self.clip_norms[j]
        norm = Normaliser(
            np.where(cols, theirs.center, norm.center), np.where(cols, theirs.scale, norm.scale), norm.angvel_scale
        )
        if spatial is not None:
            spatial = spatial.copy()
            spatial[:, cols] = self.spatial[level][j][
                np.ix_(np.round(positions).astype(np.int64), np.flatnonzero(cols))
            ]
        return crop, np.where(cols, other.sigma, sigma), norm, spatial

    def train_dataloader(self) -> DataLoader:
        workers = self.hparams.get("num_workers", 0)
        # torch warns that __len__ may be wrong with workers unless each draws its own share: CropStream's do
        warnings.filterwarnings("ignore", message="Your `IterableDataset` has `__len__` defined", category=UserWarning)
        return EpochLoader(CropStream(self, self.rank), batch_size=None, num_workers=workers)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_batches, batch_size=None, num_workers=0)

    def state_dict(self) -> dict[str, Any]:
        return {"epoch_counter": self.epoch_counter}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.epoch_counter = int(state_dict["epoch_counter"])
