"""A BVH file's rotation angles made continuous for cleaning, and the result put back as the file stores them.

A file stores each rotation as three Euler angles, and two kinds of jump in those numbers are not motion:

- a **wrap**: one angle steps by 360° (a file that keeps its angles within ±180° or 0–360°);
- a **flip**: near gimbal lock (the middle angle near ±90°) many exporters switch to the other Euler triple of
  the same rotation, ``(a, b, c) → (a + 180, 180 - b, c + 180)`` (true of every order of three different axes),
  so two angles jump by about 180° and the third mirrors, while the joint turns by a few degrees.

A smoother or gap filler working channel by channel would turn a limb through either jump (a reviewer's sweep
found forearms turned by 170°). ``StoredBranches.of`` makes the angles continuous: wraps as
``fill.unwrap_observed`` takes them (without reading masked samples), then flips: between two neighbouring
fully observed frames of a joint, the other triple is taken when it is nearer the previous one by more than
half a turn (the sum of the three angle steps, each the short way round). ``restore`` inverts both on the
cleaned angles, so the output keeps the file's own branches: a sample that was not changed is written exactly
as it was stored (the root's and every unscored channel included), a changed one on the branch of the stored
sample it replaces, and in a file that keeps its angles within [-180°, 180°] (or [0°, 360°]) every sample is put
in that range too (a file mixing the two: each column in its own). Where a joint's triple flips an odd number of
times, the clip is cleaned on the file's own triples for most of its frames (the branch a network was trained on);
where the file flips a joint and keeps its middle angle within ±90°, every changed triple is written that way too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapnet.fill import turn_range_low, unwrap_observed
from mocapnet.kinematics import wrap_deg, wrap_near
from mocapnet.motion import Skeleton

#: The other Euler triple of the same rotation: ``(a, b, c) → (a + 180, 180 - b, c + 180)`` is ``FLIP_SIGN · x +
#: FLIP_OFFSET`` (degrees).
FLIP_SIGN = np.array([1.0, -1.0, 1.0])
FLIP_OFFSET = np.array([180.0, 180.0, 180.0])
#: ``flip_triples`` twice adds a turn to the first and third angles (``unflip_triples`` takes it off).
UNFLIP_TURNS = np.array([360.0, 0.0, 360.0])
#: A restored value this close (degrees) to the stored one is the stored one (the round trip's float error).
SAME_DEG = 1e-9
#: A step is taken as a flip only when the other triple shortens it by more than this (degrees, the sum over the
#: three angles): an exporter's flip shortens it by about 360°, while noise near gimbal lock seldom makes two
#: angles jump by 180° at once.
FLIP_GAIN_DEG = 180.0


def flip_triples(triples: np.ndarray) -> np.ndarray:
    """The other Euler triple of each rotation ``[..., 3]`` (degrees), for any order of three different axes."""
    return FLIP_SIGN * triples + FLIP_OFFSET


def unflip_triples(triples: np.ndarray) -> np.ndarray:
    """The inverse of ``flip_triples``: ``(a, b, c) → (a - 180, 180 - b, c - 180)``."""
    return flip_triples(triples) - UNFLIP_TURNS


def triple_columns(skeleton: Skeleton) -> list[np.ndarray]:
    """The rotation columns ``[3]`` (file order) of every joint rotated about three different axes."""
    return [c for seq, _, cols in skeleton.rotation_groups if len(set(seq)) == 3 == len(seq) for c in cols]


def flip_states(triples: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Per frame, whether a joint's Euler triple is to be flipped (``flip_triples``) to continue the previous
    fully observed frame's (bool ``[T]``): ``triples [T, 3]`` degrees, ``observed [T]`` bool. Flipping both of
    two neighbours keeps their step, so each step between observed frames toggles the state when the flipped
    triple is nearer its predecessor than the triple itself by more than ``FLIP_GAIN_DEG``; frames not observed
    keep the state before them (after them, before the first)."""
    seen = np.flatnonzero(observed)
    state = np.zeros(len(triples), dtype=bool)
    if len(seen) < 2:
        return state
    prev, cur = triples[seen[:-1]], triples[seen[1:]]
    same = np.abs(wrap_deg(cur - prev)).sum(axis=1)
    other = np.abs(wrap_deg(flip_triples(cur) - prev)).sum(axis=1)
    at_seen = np.concatenate([[0], np.cumsum(other < same - FLIP_GAIN_DEG)]) % 2 == 1
    holder = np.clip(np.searchsorted(seen, np.arange(len(triples)), side="right") - 1, 0, None)
    return at_seen[holder]


@dataclass(frozen=True)
class StoredBranches:
    """How a file's angles were made continuous (``of``), to put cleaned angles back as it stores them
    (``restore``). ``stored [T, C]``: the file's values; ``mask [T, C]``: the missing samples; ``unwrapped``:
    after ``unwrap_observed``; ``flipped``: per triple joint (``triple_columns`` order) its flip states ``[T]``
    and the multiples of 360° ``[T, 3]`` added to keep flipped runs continuous."""

    stored: np.ndarray
    mask: np.ndarray
    rotation: np.ndarray
    unwrapped: np.ndarray
    triples: list[np.ndarray]
    flipped: list[tuple[np.ndarray, np.ndarray]]

    @classmethod
    def of(cls, stored: np.ndarray, mask: np.ndarray, skeleton: Skeleton) -> tuple[StoredBranches, np.ndarray]:
        """``(branches, continuous [T, C])`` for a file's ``stored`` channels (degrees and its position units)
        with ``mask`` (True = missing; any value there)."""
        rotation = skeleton.rotation_mask
        unwrapped = unwrap_observed(stored, mask, rotation)
        out = unwrapped.copy()
        triples, flipped = triple_columns(skeleton), []
        for cols in triples:
            x, observed = out[:, cols], ~mask[:, cols].any(axis=1)
            state = flip_states(x, observed)
            # most of the clip on the file's own triples, the branch a network saw
            if 2 * np.count_nonzero(state & observed) > np.count_nonzero(observed):
                state = ~state
            moved = np.where(state[:, None], flip_triples(x), x)
            # a run starts (at an observed frame: states change only there) on the branch nearest the observed frame
            # before it, never a masked placeholder; later steps inside a run stay as unwrapped, so the turns
            # 'unwrap_observed' kept across gaps stay too
            starts = np.flatnonzero(state[1:] != state[:-1]) + 1
            seen = np.flatnonzero(observed)
            before = seen[np.searchsorted(seen, starts) - 1]
            jump = np.zeros_like(moved)
            jump[starts] = wrap_near(moved[starts], moved[before]) - moved[starts]
            shift = np.cumsum(jump, axis=0)
            out[:, cols] = moved + shift
            flipped.append((state, shift))
        return cls(stored, mask, rotation, unwrapped, triples, flipped), out

    def _canonical(self, cols: np.ndarray) -> bool:
        """Whether a joint's stored triples (observed frames) all keep the middle angle within [-90°, 90°], as an
        exporter that flips to the other triple near gimbal lock writes them."""
        seen = ~self.mask[:, cols].any(axis=1)
        return bool(seen.any() and (np.abs(wrap_deg(self.stored[seen, cols[1]])) <= 90.0).all())

    def restore(self, cleaned: np.ndarray) -> np.ndarray:
        """``cleaned [T, C]`` (continuous, as ``of`` gave the angles) on the file's branches: flips and wraps
        undone, unchanged samples exactly as stored, and a column the file keeps within one turn kept there. A joint
        whose file flips its triples and keeps the middle angle within ±90° (``_canonical``) gets every changed or
        filled triple that way too (a gap filled across a flip would otherwise carry the triple it started on)."""
        out = np.array(cleaned, dtype=np.float64, copy=True)
        for cols, (state, shift) in zip(self.triples, self.flipped):
            back = out[:, cols] - shift
            back = np.where(state[:, None], unflip_triples(back), back)
            if state.any() and self._canonical(cols):  # the exporter flips: keep every triple as it would write it
                back = np.where(np.abs(wrap_deg(back[:, 1:2])) > 90.0, unflip_triples(back), back)
            out[:, cols] = back
        out -= self.unwrapped - self.stored  # the wraps (masked samples: their holder's; zero off the rotations)
        seen = ~self.mask & self.rotation
        low = _range_lows(np.where(seen, self.stored, np.inf).min(0), np.where(seen, self.stored, -np.inf).max(0))
        wrap = np.isfinite(low) & ((out.min(0) < low) | (out.max(0) > low + 360.0))
        out[:, wrap] = np.mod(out[:, wrap] - low[wrap], 360.0) + low[wrap]
        step = out - self.stored
        step = np.where(self.rotation, wrap_deg(step), step)  # a position differing by 360 units is not the same
        same = (np.abs(step) <= SAME_DEG) & ~self.mask
        out[same] = self.stored[same]
        return out


def _range_lows(lowest: np.ndarray, highest: np.ndarray) -> np.ndarray:
    """Per column, the lower end (degrees) of the one-turn range its observed angles (``lowest`` … ``highest``,
    ``[C]``; inf / -inf for none) are stored in: the file's when all of them share one, -180 for [-180, 180]
    (values within [0, 180] fit both), 0 for [0, 360]; else each column's own; NaN for none (stored continuously
    or not observed; ``fill.turn_range_low``)."""
    seen = np.isfinite(lowest)
    if seen.any():
        whole = turn_range_low(lowest[seen].min(), highest[seen].max())
        if np.isfinite(whole):
            return np.where(seen, whole, np.nan)
    return np.where(seen, turn_range_low(lowest, highest), np.nan)
