"""The learned cleaners as angle-space methods: ``ebf`` and its named variants, ``ebd``, ``ebd+ebf``, and the
ablations ``bf``, ``nn``.

EBF variants (issue 11): ``ebf-paper`` the paper's network (σ-only Gaussian filter per channel and frame, no
bias); ``ebf-bias`` the same with a per-channel bias (residual) output; ``ebf-free`` a free-shape kernel
(softmax over the 31 taps, with or without the bias output); ``ebf`` the best shipped variant for the clip's
skeleton (``"ebf": true`` in ``mocapnet/checkpoints/index.json``; its recipe is in ``mocapnet methods``).
A variant name given a checkpoint checks that the checkpoint is that variant; ``ebf=FILE`` takes any.

    --method ebf                       the checkpoint shipped for the clip's skeleton (mocapnet/checkpoints)
    --method ebf=run/best.ckpt         a trained checkpoint
    --method ebd+ebf=ebd.ckpt,ebf.ckpt gap filling by EBD, then denoising by EBF
    --method ebf:mode=windowed         streaming-equivalent windowed mode (default: sequence)
    --method ebf:mode=windowed,checkpoints=run/best.ckpt   both
    --method ebd+ebf=ebd.ckpt,ebf.ckpt:mode=windowed       both, with two checkpoints

Gaps are filled by linear interpolation before any network (an EBD: by the interpolation it was trained to
correct, ``EBD.interpolate``); EBD's fill of each gap is then blended with the
better interpolation for its length and self-checked (``mocapnet.nn.ebd.blend_gaps``).
Only the scored channels change. torch is imported when a method is built, never by ``import mocapnet``.

Test-time augmentation (a self-ensemble, option ``tta``) and blending (option ``blend``) of any single network:

    --method ebf:tta=reverse           mean of the clip cleaned as it is and cleaned time-reversed (2 passes)
    --method ebf:tta=warp              mean over the clip at 1×, 0.9× and 1.1× speed (3 passes)
    --method ebf:tta=reverse+warp      both (6 passes)
    --method ebf:blend=gaussian-tuned  a blend, not EBF: mean of EBF's output and that angle method's
    --method ebf:blend=gaussian-cv,blend_weight=sure   the same, the network's weight chosen per clip by SURE

Each pass is ``infer.clean_channels`` on a transformed copy (reversed in time; resampled by linear
interpolation of the unwrapped channels), whose output is transformed back; the passes' scored channels are
averaged on the circle (``tta_mean``). A reversed clip's root angular velocity is what
``features.root_angular_velocity`` gives on the reversed channels (``clean_channels`` computes it).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

from mocapnet.fill import gap_lengths, lerp_fill
from mocapnet.kinematics import wrap_deg, wrap_near
from mocapnet.methods.registry import MethodContext, build_method, register
from mocapnet.motion import Motion, Skeleton
from mocapnet.nn.variants import SHORT_MAX_S, VARIANTS, accepts, method_of, serves
from mocapnet.selfcheck import NOISE_ORDERS, limit_change
from mocapnet.sure import sure_mix

_HELP = (
    "{what}; checkpoint: NAME=PATH, default: the shipped one for the skeleton; options mode=sequence|windowed, "
    "tta=reverse|warp|reverse+warp (self-ensemble){extra}"
)
_EBD_EXTRA = (
    ", rehearse=N (per gap N stand-in gaps where the truth is known; a gap keeps the share of the network's correction"
    " that fitted them), rehearse_mix=0 (all or nothing: interpolate the gaps where the network lost),"
    " rehearse_pool=W (0-1: weight of the share fitted to all the clip's stand-ins together),"
    " rehearse_shrink=1 (with the share: each gap's share shrunk by how much its stand-ins disagree, so a share"
    " they barely support goes toward the interpolation),"
    " rehearse_near=S (seconds: gaps up to this long get the stand-ins nearest to them instead of ones anywhere in"
    " the clip), rehearse_seed=N (the seed the stand-ins are placed with; default 0),"
    " rehearse_passes=P (hide the stand-ins in P network passes instead of one, so each pass damages the clip"
    " less),"
    " short_pool=1 (gaps shorter than the gate's end keep one share fitted to all their stand-ins together,"
    " instead of each gap's verdict),"
    " gate_end=S (seconds: where the length gate ends — shorter gaps keep a share of the network's correction"
    " growing with their length; with the rehearsal, gaps at least this long get the fitted share, shorter ones"
    " its all-or-nothing verdict),"
    " short=PATH|auto|off (a second EBD for the gaps shorter than short_max_s, default 0.2 s: each gap is filled by"
    " the network made for its length, both with the same options; auto, the default: the shipped ebd's own"
    " short-gap network when the main network is the shipped one, none otherwise)"
)
_EBF_EXTRA = (
    ", blend=METHOD (mean with an angle method; blend_weight=W: the network's weight in [0, 1], or sure: chosen per"
    " clip by Stein's unbiased risk estimate), anchor=METHOD (the self-check caps the distance from that method's"
    " output instead of from the input)"
    ", limit=K (self-check: each channel changes by at most K x the noise its input shows; 0: off),"
    " noise_order=2|3|4 (the differences that noise is estimated from; higher counts less of fast motion as noise)"
)
_HELP_PAIR = (
    "{what}; checkpoints: EBD,EBF, default: the shipped ones for the skeleton; options mode=sequence|windowed, "
    "short=PATH|auto|off (EBD's network for gaps shorter than short_max_s; auto: the shipped ebd's, with it)"
)
_BLEND_OPTIONS = (
    "rehearse",
    "rehearse_margin",
    "rehearse_min_s",
    "rehearse_mix",
    "rehearse_pool",
    "rehearse_passes",
    "rehearse_shrink",
    "rehearse_near",
    "rehearse_seed",
    "short_pool",
    "gate_end",
)
_INDEX = Path(__file__).resolve().parents[1] / "checkpoints" / "index.json"


T = TypeVar("T")


def per_skeleton(load: Callable[[Skeleton], T]) -> Callable[[Skeleton], T]:
    """``load`` called once per skeleton topology (``Skeleton.topology``) and its result reused for every later
    skeleton of that topology. What depends on more than the topology (the frame rate) is the caller's to check
    on every call."""
    cache: dict[tuple, T] = {}

    def cached(skeleton: Skeleton) -> T:
        key = skeleton.topology()
        if key not in cache:
            cache[key] = load(skeleton)
        return cache[key]

    return cached


def _resolver(method: str, path: str | None) -> Callable[[Motion], object]:
    """A function giving the loaded model for a motion: from ``path`` (loaded now, so a bad path fails at
    build time) or the shipped checkpoint of ``method`` for the motion's skeleton (loaded once per skeleton)."""
    from mocapnet.nn.checkpoints import shipped_checkpoint
    from mocapnet.nn.infer import check_skeleton, load_model

    if path is not None:
        if not Path(path).is_file():
            raise FileNotFoundError(f"{method}: checkpoint {path} not found")
        model = load_model(path)
        kind = method_of(type(model).__name__, dict(model.hparams))
        if not accepts(method, kind):
            raise ValueError(f"{method}: {path} holds a {type(model).__name__} network ({kind}), not {method}")

        def given(motion: Motion) -> object:
            check_skeleton(model, motion.skeleton, f"checkpoint {path}", motion.fps)
            return model

        return given

    def load_shipped(skeleton: Skeleton) -> tuple[Path, object]:
        ckpt = shipped_checkpoint(method, skeleton)
        return ckpt, load_model(ckpt)

    loaded = per_skeleton(load_shipped)

    def shipped(motion: Motion) -> object:
        ckpt, model = loaded(motion.skeleton)
        check_skeleton(model, motion.skeleton, f"shipped checkpoint {ckpt.name}", motion.fps)
        return model

    return shipped


#: ``short=`` values that turn the short-gap network off (the registry reads ``none`` as None, ``false`` as False).
SHORT_OFF = (None, False, "off", "none")


def _short_resolver(
    main: str | None, short: str | bool | None, short_max_s: float | None, label: str = "ebd"
) -> Callable[[Motion], tuple[object, float] | None]:
    """A function giving, for a motion, EBD's short-gap network and the gap length (s) below which it fills, or
    None. ``short``: a path (loaded now; gaps under ``short_max_s``, default ``SHORT_MAX_S``); ``"auto"``: the
    shipped partner of the skeleton's ``ebd`` (``checkpoints.shipped_short``; its ``max_s`` unless
    ``short_max_s`` is given) when the main network is the shipped one (``main`` None), none when ``main`` is a
    path; ``off``/``none``/``false``: none. ValueError for a ``short_max_s`` without a short network."""
    if isinstance(short, str) and short.strip().lower() in SHORT_OFF:
        short = None
    if not (short is None or short is False or isinstance(short, str)):
        raise ValueError(f"{label}: short=PATH|auto|off names EBD's network for short gaps, got {short!r}")
    off = short is None or short is False or (short == "auto" and main is not None)
    if short_max_s is not None:
        if isinstance(short_max_s, (bool, str)) or not (np.isfinite(float(short_max_s)) and short_max_s > 0):
            raise ValueError(f"{label}: short_max_s must be a time > 0 (s), got {short_max_s!r}")
        if off:
            raise ValueError(f"{label}: short_max_s is for a short-gap network (short=PATH, or the shipped ebd's)")
    if off:
        return lambda motion: None
    if short != "auto":
        given = _resolver("ebd", short)
        max_s = SHORT_MAX_S if short_max_s is None else float(short_max_s)
        return lambda motion: (given(motion), max_s)
    from mocapnet.nn.checkpoints import shipped_short
    from mocapnet.nn.infer import check_skeleton, load_model

    def load_shipped(skeleton: Skeleton) -> tuple[Path, object, float] | None:
        found = shipped_short(skeleton)
        return None if found is None else (found[0], load_model(found[0]), found[1])

    loaded = per_skeleton(load_shipped)

    def shipped(motion: Motion) -> tuple[object, float] | None:
        found = loaded(motion.skeleton)
        if found is None and short_max_s is not None:
            raise ValueError(
                f"{label}: short_max_s given, but the ebd shipped for this skeleton ({motion.skeleton.describe()}) "
                "has no short-gap network: name one with short=PATH"
            )
        if found is None:
            return None
        ckpt, model, max_s = found
        check_skeleton(model, motion.skeleton, f"shipped checkpoint {ckpt.name}", motion.fps)
        return model, max_s if short_max_s is None else float(short_max_s)

    return shipped


def fill_by_gap_length(
    mask: np.ndarray,
    max_frames: float,
    long_fill: Callable[[], np.ndarray],
    short_fill: Callable[[], np.ndarray],
) -> np.ndarray:
    """``by_gap_length`` computing only the fills it needs: ``long_fill()`` alone when no gap of ``mask [T, C]``
    (True = missing) is shorter than ``max_frames`` frames, ``short_fill()`` alone when every gap is (each fill
    ``[T, C]`` keeps the observed samples, so either gives them), both otherwise."""
    lengths = gap_lengths(mask)
    short = (lengths > 0) & (lengths < max_frames)
    if not short.any():
        return long_fill()
    if not (mask & ~short).any():
        return short_fill()
    return np.where(short, short_fill(), long_fill())


def ebd_raw_filler(
    main: str | None = None, short: str | bool | None = "auto", short_max_s: float | None = None, mode: str = "sequence"
) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """EBD's own fill as it comes (no blend, no self-check): ``fill(motion, mask [T, C]) -> [T, C]`` degrees, by
    the network ``main`` (a path; default the shipped ``ebd`` of the motion's skeleton) and, for gaps shorter
    than its length, the short-gap network (``_short_resolver``: ``short=PATH``, the shipped partner, or none)."""
    from mocapnet.nn.infer import clean_channels

    network = _resolver("ebd", main)
    short_for = _short_resolver(main, short, short_max_s)
    _check_mode(mode)

    def fill(motion: Motion, mask: np.ndarray) -> np.ndarray:
        def raw(model: object) -> np.ndarray:
            return clean_channels(model, motion.channels, mask, motion.skeleton, motion.fps, mode, gap_blend=None)

        pair = short_for(motion)
        if pair is None:
            return raw(network(motion))
        return fill_by_gap_length(mask, pair[1] * motion.fps, lambda: raw(network(motion)), lambda: raw(pair[0]))

    return fill


def _index_entries() -> list[dict]:
    """The entries of the shipped ``checkpoints/index.json``, read as JSON (no torch); none when it is absent."""
    return json.loads(_INDEX.read_text())["checkpoints"] if _INDEX.exists() else []


def shipped_methods(skeleton: Skeleton) -> dict[str, dict]:
    """The learned methods shipped for ``skeleton``'s topology (``_index_entries``), each with its index entry
    (``corpus``, training ``fps``, ...), e.g. ``{"ebf": {...}, "ebd": {...}}``."""
    from mocapnet.nn.features import topology_hash

    mine = topology_hash(skeleton)
    entries = [e for e in _index_entries() if e.get("skeleton_hash") == mine]
    return {m: e for m in (*(v.name for v in VARIANTS), "ebf") for e in entries if serves(e, m)}


def _shipped_ebf_recipes() -> str:
    """What ``ebf`` runs, per corpus, from the shipped index (``_index_entries``)."""
    entries = [e for e in _index_entries() if e.get("ebf")]
    if not entries:
        return "none shipped"
    return "; ".join(f"{e['corpus']}: {e['method']} ({e.get('recipe', '')}, {e.get('budget', '')})" for e in entries)


def _shipped_ebd_networks() -> str:
    """Which networks ``ebd`` runs, per corpus, from the shipped index (a main one, and its short-gap partner)."""
    parts = []
    for e in (e for e in _index_entries() if serves(e, "ebd")):
        pair = f" with {e['short']['file']} for gaps under {e['short']['max_s']:g} s" if e.get("short") else ""
        parts.append(f"{e['corpus']}: {e['file']}{pair}")
    return "; ".join(parts) or "none shipped"


def _paths(checkpoints: Sequence[str] | str) -> list[str]:
    """``checkpoints`` as a list (the ``name:checkpoints=path`` option form gives one string)."""
    return [checkpoints] if isinstance(checkpoints, str) else list(checkpoints)


def _check_mode(mode: str) -> str:
    from mocapnet.nn.infer import MODES

    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    return mode


#: Speeds (source frames per resampled frame) of the extra passes of ``tta=warp``, besides 1.
WARP_RATES = (0.9, 1.1)
TTA_PARTS = ("reverse", "warp")


def tta_passes(tta: str | None) -> tuple[tuple[bool, float], ...]:
    """The passes ``(time reversed, speed)`` of a ``tta`` option: None or ``"none"`` one plain pass;
    ``"reverse"``, ``"warp"`` or ``"reverse+warp"`` add reversed and/or ``WARP_RATES`` copies. The plain pass
    comes first. ValueError naming the parts for anything else."""
    parts = [] if tta in (None, "none") else str(tta).split("+")
    if any(p not in TTA_PARTS for p in parts) or len(set(parts)) != len(parts):
        raise ValueError(f"tta must be none or a '+'-joined set of {', '.join(TTA_PARTS)}, got {tta!r}")
    rates = (1.0, *WARP_RATES) if "warp" in parts else (1.0,)
    directions = (False, True) if "reverse" in parts else (False,)
    return tuple((rev, rate) for rev in directions for rate in rates)


def warp_positions(n_frames: int, rate: float) -> np.ndarray:
    """Fractional source frames ``[L]`` of a clip of ``n_frames`` played at ``rate`` × its speed (``rate`` < 1:
    slower, more frames): ``L = round((T-1)/rate) + 1`` evenly spaced positions from 0 to ``T-1``, so both
    ends are kept exactly."""
    length = max(2, int(round((n_frames - 1) / rate)) + 1)
    return np.linspace(0.0, n_frames - 1.0, length)


def augmented_pass(
    clean: Callable[[np.ndarray, np.ndarray], np.ndarray],
    channels: np.ndarray,
    mask: np.ndarray,
    idx: np.ndarray,
    reverse: bool,
    rate: float,
) -> np.ndarray:
    """Scored channels ``[T, C_s]`` (degrees) of ``clean(channels', mask') -> [T', C]`` run on a transformed copy
    of ``channels [T, C]`` / ``mask [T, C]``, transformed back: time-reversed when ``reverse``; resampled to
    ``rate`` × speed when ``rate != 1`` (gaps filled linearly first, channels unwrapped and interpolated; a
    resampled sample is missing when either source neighbour is), the output unwrapped and resampled back."""
    if reverse:
        channels, mask = channels[::-1], mask[::-1]
    if rate != 1.0 and len(channels) > 2:
        from mocapnet.nn.data import resample

        positions = warp_positions(len(channels), rate)
        filled = np.unwrap(lerp_fill(channels, mask), period=360.0, axis=0)
        out = clean(resample(filled, positions), resample(mask.astype(np.float64), positions) > 0)[:, idx]
        back = np.arange(len(channels)) * (len(positions) - 1) / (len(channels) - 1)
        out = resample(np.unwrap(out, period=360.0, axis=0), back)
    else:
        out = clean(channels, mask)[:, idx]
    return out[::-1] if reverse else out


def tta_mean(outputs: Sequence[np.ndarray]) -> np.ndarray:
    """Circular mean (degrees) of same-shaped arrays: each wrapped to within 180° of the first, then averaged,
    so the result stays on the first one's branch."""
    ref = outputs[0]
    return np.mean([wrap_near(o, ref) for o in outputs], axis=0)


def self_ensemble(
    clean: Callable[[np.ndarray, np.ndarray], np.ndarray],
    channels: np.ndarray,
    mask: np.ndarray,
    idx: np.ndarray,
    passes: Sequence[tuple[bool, float]],
) -> np.ndarray:
    """``clean(channels [T, C], mask [T, C]) -> [T, C]`` averaged over ``passes`` (``tta_passes``; the first
    plain) on the scored channels ``idx``: ``[T, C]``, the other channels as the plain pass leaves them."""
    result = clean(channels, mask)
    if len(passes) > 1:
        extra = [augmented_pass(clean, channels, mask, idx, rev, rate) for rev, rate in passes[1:]]
        result[:, idx] = tta_mean([result[:, idx], *extra])
    return result


def by_gap_length(long_fill: np.ndarray, short_fill: np.ndarray, mask: np.ndarray, max_frames: float) -> np.ndarray:
    """``long_fill [T, C]`` with the samples of every gap shorter than ``max_frames`` frames taken from
    ``short_fill [T, C]`` (a gap: a run of missing frames of the channels that miss together, ``fill.gap_lengths``;
    ``mask [T, C]`` True = missing). Observed samples come from ``long_fill``."""
    lengths = gap_lengths(mask)
    return np.where((lengths > 0) & (lengths < max_frames), short_fill, long_fill)


def _blend_partner(method: str, blend: str | None, context: MethodContext, option: str = "blend") -> Callable | None:
    """The angle method ``blend`` names (given as ``option``), built with ``context`` (None when not asked for);
    ValueError for a gap filler (EBD) or a method that is not in the angle space."""
    if blend is None:
        return None
    if method == "ebd":
        raise ValueError(f"ebd: {option} is for the denoisers (EBF variants, bf, nn), not for gap filling")
    return build_method(str(blend), context, space="angles").clean


def _blend_weight(method: str, weight: float | str | None, blending: bool) -> float | str | None:
    """The ``blend_weight`` option checked: None (the mean), ``"sure"`` or a number in [0, 1]; ValueError
    naming the method otherwise, for ``ebd`` (no blends), or when there is no ``blend`` to weigh."""
    if weight is None:
        return None
    if method == "ebd":
        raise ValueError("ebd: blend_weight is for the denoisers (EBF variants, bf, nn), not for gap filling")
    if not blending:
        raise ValueError(f"{method}: blend_weight weighs a blend; give blend=METHOD too")
    if weight == "sure":
        return weight
    if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0.0 <= weight <= 1.0:
        raise ValueError(f"{method}: blend_weight must be sure or a number in [0, 1], got {weight!r}")
    return float(weight)


def sure_blend(
    noisy: Motion,
    mask: np.ndarray,
    idx: np.ndarray,
    network: Callable[[Motion], np.ndarray],
    partner: Callable[[Motion], np.ndarray],
    order: int = 2,
) -> tuple[np.ndarray, float]:
    """``(out [T, C], w)``: ``network(noisy) -> [T, C]`` with its scored channels ``idx`` mixed with
    ``partner``'s by the clip's SURE weight ``w`` of the network (``mocapnet.sure.sure_mix`` on the observed
    samples of ``mask [T, C]``, True = missing; missing samples are bridged linearly for the probed runs and
    left out of the estimate; noise from differences of ``order``). The other channels are the network's."""
    seen = lerp_fill(noisy.channels[:, idx], mask[:, idx])

    def scored(clean: Callable[[Motion], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
        def run(values: np.ndarray) -> np.ndarray:
            channels = noisy.channels.copy()
            channels[:, idx] = values
            return clean(noisy.with_channels(channels))[:, idx]

        return run

    out = network(noisy)
    theirs = partner(noisy)[:, idx]
    mixed, w = sure_mix(seen, ~mask[:, idx], out[:, idx], theirs, scored(network), scored(partner), order)
    out[:, idx] = mixed
    return out, w


def _single(method: str):
    def factory(
        context: MethodContext,
        checkpoints: Sequence[str] | str = (),
        mode: str = "sequence",
        limit: float | None = None,
        noise_order: int | None = None,
        tta: str | None = None,
        blend: str | None = None,
        blend_weight: float | str | None = None,
        anchor: str | None = None,
        rehearse: int | None = None,
        rehearse_margin: float | None = None,
        rehearse_min_s: float | None = None,
        rehearse_mix: int | None = None,
        rehearse_pool: float | None = None,
        rehearse_passes: int | None = None,
        rehearse_shrink: int | None = None,
        rehearse_near: float | None = None,
        rehearse_seed: int | None = None,
        short_pool: int | None = None,
        gate_end: float | None = None,
        short: str | bool | None = "auto",
        short_max_s: float | None = None,
    ):
        """``limit``: EBF's self-check factor (``selfcheck.limit_change``; default: the checkpoint's, 0: off).
        ``noise_order``: the order of the differences the self-check estimates the input's noise from
        (``selfcheck.noise_level``; default 2; 3 or 4 let less of fast motion count as noise).
        ``tta``: the self-ensemble (``tta_passes``). ``blend``: an angle method whose output is averaged with
        the network's (weight 1/2, on the circle) — a blend, reported under its own method string.
        ``blend_weight``: the network's weight in that blend, a number in [0, 1] or ``sure``: per clip, the weight
        that minimises Stein's unbiased estimate of the error (``mocapnet.sure.sure_mix``; each cleaner runs
        once more per probe, ``sure.PROBES``). ``anchor``:
        an angle method the self-check measures the network's change from (``limit_change(anchor=…)``: each
        channel's RMS distance from that method's output capped at ``limit`` × the input's noise).
        ``rehearse``, ``rehearse_margin``, ``rehearse_min_s``, ``rehearse_mix``, ``rehearse_pool``,
        ``rehearse_passes``, ``rehearse_shrink``, ``rehearse_near``,
        ``rehearse_seed``, ``short_pool``: EBD's rehearsal check (``ebd.GapBlend``;
        default: the checkpoint's blend; ``rehearse=0``: off). ``gate_end``: EBD's length gate ends here (s;
        ``GapBlend.gate_s`` keeps its start). ``short``: an EBD checkpoint for the gaps shorter than
        ``short_max_s`` (s), run with the same options (``fill_by_gap_length``); ``auto`` (default): the shipped
        ``ebd``'s own short-gap network when the main one is shipped too; ``off`` (or ``none``): the main network
        alone (``_short_resolver``)."""
        from mocapnet.nn.ebd import GapBlend, as_blend
        from mocapnet.nn.features import scored_index
        from mocapnet.nn.infer import clean_channels

        checkpoints = _paths(checkpoints)
        if len(checkpoints) > 1:
            raise ValueError(f"{method} takes one checkpoint, got {len(checkpoints)}")
        if method != "ebd" and (short != "auto" or short_max_s is not None):
            raise ValueError(f"{method}: short and short_max_s name EBD's short-gap network (ebd only)")
        main = checkpoints[0] if checkpoints else None
        short_for = _short_resolver(main, short, short_max_s) if method == "ebd" else (lambda motion: None)
        resolve = _resolver(method, main)
        _check_mode(mode)
        if limit is not None and not (isinstance(limit, (int, float)) and limit >= 0):
            raise ValueError(f"{method}: limit must be a number >= 0, got {limit!r}")
        if noise_order is not None and (
            method == "ebd" or isinstance(noise_order, bool) or noise_order not in NOISE_ORDERS
        ):
            raise ValueError(
                f"{method}: noise_order is the EBF self-check's, one of {NOISE_ORDERS}; got {noise_order!r}"
            )
        try:
            passes = tta_passes(tta)
        except ValueError as exc:
            raise ValueError(f"{method}: {exc}") from None
        partner = _blend_partner(method, blend, context)
        weight = _blend_weight(method, blend_weight, partner is not None)
        anchored = _blend_partner(method, anchor, context, option="anchor")
        rehearsal = {
            k: v
            for k, v in (
                ("rehearsals", rehearse),
                ("rehearse_margin", rehearse_margin),
                ("rehearse_min_s", rehearse_min_s),
                ("rehearse_mix", rehearse_mix),
                ("rehearse_pool", rehearse_pool),
                ("rehearse_passes", rehearse_passes),
                ("rehearse_shrink", rehearse_shrink),
                ("rehearse_near_s", rehearse_near),
                ("rehearse_seed", rehearse_seed),
                ("short_pool", short_pool),
                ("gate_end", gate_end),
            )
            if v is not None
        }
        if rehearse is not None and (isinstance(rehearse, bool) or not isinstance(rehearse, int)):
            raise ValueError(f"{method}: rehearse is a whole number of stand-in gaps, got {rehearse!r}")
        if any(isinstance(v, (bool, str)) for v in rehearsal.values()):
            raise ValueError(f"{method}: {', '.join(_BLEND_OPTIONS)} take numbers, got {rehearsal}")
        if rehearsal and method != "ebd":
            raise ValueError(f"{method}: {', '.join(_BLEND_OPTIONS)} are EBD options")
        gate_end = rehearsal.pop("gate_end", None)
        if gate_end is not None and not (np.isfinite(float(gate_end)) and float(gate_end) > 0):
            raise ValueError(f"{method}: gate_end must be a time > 0 (s), got {gate_end!r}")
        if rehearsal:
            try:
                checked = as_blend(rehearsal)
            except ValueError as exc:
                raise ValueError(f"{method}: {exc}") from None
            if not all(np.isfinite(float(getattr(checked, k))) for k in rehearsal):
                raise ValueError(f"{method}: rehearse, rehearse_margin and rehearse_min_s must be finite")
            rehearsal = {k: getattr(checked, k) for k in rehearsal}  # the values as_blend checked and converted

        def blend_of(model) -> GapBlend | str:
            """The model's blend with the options given (``"checkpoint"``: as stored)."""
            if not rehearsal and gate_end is None:
                return "checkpoint"
            stored = model.blend()
            gate = stored.gate_s if gate_end is None else (stored.gate_s[0], float(gate_end))
            if gate[1] <= gate[0]:
                raise ValueError(f"{method}: gate_end {gate[1]:g} s must be after the gate's start {gate[0]:g} s")
            return dataclasses.replace(stored, **rehearsal, gate_s=gate)

        def run(model, noisy: Motion, mask: np.ndarray) -> np.ndarray:
            sk, fps = noisy.skeleton, noisy.fps
            gap_blend = blend_of(model)

            own = anchored is None and noise_order in (None, 2)  # else this check replaces the network's own
            own_check = limit if own else 0.0
            factor = float(model.hparams.get("change_limit", 0.0)) if limit is None else limit
            idx = scored_index(sk)

            def once(channels: np.ndarray, gaps: np.ndarray) -> np.ndarray:
                return clean_channels(model, channels, gaps, sk, fps, mode, gap_blend, change_limit=own_check)

            def network(motion: Motion) -> np.ndarray:
                out = self_ensemble(once, motion.channels, mask, idx, passes)
                if not own and factor > 0:
                    seen = lerp_fill(motion.channels[:, idx], mask[:, idx])
                    base = None if anchored is None else anchored(motion, mask)[:, idx]
                    out[:, idx] = limit_change(seen, out[:, idx], factor, anchor=base, order=noise_order or 2)
                return out

            if partner is None:
                return network(noisy)
            if weight == "sure":
                return sure_blend(noisy, mask, idx, network, lambda m: partner(m, mask), noise_order or 2)[0]
            out = network(noisy)
            ours, theirs = out[:, idx], partner(noisy, mask)[:, idx]
            if weight is None:
                out[:, idx] = tta_mean([ours, theirs])
            else:
                out[:, idx] = ours + (1.0 - weight) * wrap_deg(theirs - ours)
            return out

        def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
            def long_fill() -> np.ndarray:
                return run(resolve(noisy), noisy, mask)

            pair = short_for(noisy)
            if pair is None:
                return long_fill()
            return fill_by_gap_length(mask, pair[1] * noisy.fps, long_fill, lambda: run(pair[0], noisy, mask))

        return clean

    return factory


_WHAT = {v.name: v.what for v in VARIANTS}
_WHAT["ebf"] += f": {_shipped_ebf_recipes()}"
_WHAT["ebd"] += f" (shipped: {_shipped_ebd_networks()})"
for _name, _what in _WHAT.items():
    _extra = _EBD_EXTRA if _name == "ebd" else _EBF_EXTRA
    register(_name, "angles", help=_HELP.format(what=_what, extra=_extra))(_single(_name))


@register("ebd+ebf", "angles", help=_HELP_PAIR.format(what="EBD fills gaps, then EBF denoises"))
def _ebd_ebf(
    context: MethodContext,
    checkpoints: Sequence[str] | str = (),
    mode: str = "sequence",
    short: str | bool | None = "auto",
    short_max_s: float | None = None,
):
    from mocapnet.nn.infer import clean_channels

    checkpoints = _paths(checkpoints)
    if len(checkpoints) not in (0, 2):
        raise ValueError(f"ebd+ebf takes two checkpoints (EBD,EBF), got {len(checkpoints)}")
    # The network's own fill: blending with interpolation (ebd.blend_gaps) assumes clean observed samples
    # and made noise+gaps worse on bandai2 fold 1 (gap error 7.49° blended vs 4.16° raw).
    fill = ebd_raw_filler(checkpoints[0] if checkpoints else None, short, short_max_s, mode)
    ebf = _resolver("ebf", checkpoints[1] if checkpoints else None)

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        filled = fill(noisy, mask)
        no_gaps = np.zeros_like(mask)
        return clean_channels(ebf(noisy), filled, no_gaps, noisy.skeleton, noisy.fps, mode)

    return clean
