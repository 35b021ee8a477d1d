"""EBD (Encoder-Bidirectional-Decoder): fills gaps (EBF paper, Sec. 3, "Gap filling").

Gaps are first interpolated (``fill.gap_fill``: linearly, or by cubic spline for gaps of at most
``spline_max_s`` seconds when that hyper-parameter is above 0, as the network was trained); per frame the input
is the normalised filled channels, the missing-sample mask and the root angular velocity. The encoder (as
EBF's) gives a ``code``-D vector; two bidirectional LSTM layers of ``hidden`` units per direction step through
the clip with ``stride`` frames per step (windowed mode: ``half`` steps each way, i.e. 15 × 4 = 60 frames); a
decoder of ``decoder_layers`` tanh layers (last one linear) gives, for every channel, a correction to the
interpolated value in channel scales.
The output replaces only the missing samples; observed samples pass through unchanged.

At inference the network's fill is not used as it comes (``blend_gaps``, issue 11): per gap (one run of
missing frames of one joint) it is blended with the better interpolation for that gap length (cubic spline
for short gaps, linear for long ones), with a weight that is 0 for one-frame gaps, grows with the gap length
and, inside a gap, grows from each edge over ``taper_s`` seconds (the network's fill is least reliable next
to the observed frames, where interpolation is best). A self-check then falls back to the interpolation for
every gap whose blended fill is less continuous than the interpolation: a fill value that could not be
reached from the observed neighbours at the channel's own speed (``speed_quantile`` of its observed
frame-to-frame steps × ``speed_factor``). Before that, a rehearsal check (``rehearse``) fills stand-in gaps of
the same channels and length where the clip observes them, and a gap whose stand-ins the interpolation filled
much better (by ``rehearse_margin``) goes to the interpolation: whether the network knows this clip is measured
on the clip itself. The blend's constants were chosen on bandai2 fold 1 only (``scripts/bench_ebd.py --tune``);
the rehearsal's on fold 1 and on 'elderly' clips with an EBD trained without them (``--compare``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from mocapnet.fill import gap_fill, gap_list
from mocapnet.kinematics import wrap_deg, wrap_near
from mocapnet.nn.base import NORMS, CleanerModule, n_inputs
from mocapnet.nn.layers import BLSTM, mlp, tapered

#: Training losses of the EBD (``EBD.loss_terms``): every missing sample's squared error alike, or each divided by
#: its gap's interpolation error: its mean square (``"relative"``) or its RMS (``"rms"``, halfway between the two).
GAP_LOSSES = ("samples", "relative", "rms")
#: ``"rms"`` divides by the gap's interpolation RMS error plus this many degrees, ``"relative"`` by its mean
#: squared error plus this squared: a gap the interpolation fills almost exactly is not weighted without bound.
GAP_LOSS_FLOOR_DEG = 1.0


class EBD(CleanerModule):
    """Encoder-Bidirectional-Decoder gap filler for ``n_channels`` scored channels (degrees)."""

    val_metric = "val/gap_err_deg"

    def __init__(
        self,
        n_channels: int,
        hidden: int = 32,
        code: int = 64,
        width: int = 128,
        encoder_layers: int = 4,
        decoder_layers: int = 4,
        dropout: float = 0.5,
        half: int = 15,
        stride: int = 4,
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        lr_patience: int = 4,
        lr_schedule: str = "plateau",
        skeleton_hash: str = "",
        fps: float = 0.0,
        corpus: str = "",
        spline_max_s: float = 0.0,
        gap_blend: dict[str, Any] | None = None,
        norm: str = "corpus",
        gap_loss: str = "samples",
    ) -> None:
        super().__init__(n_channels, lr, weight_decay, lr_patience)
        if gap_loss not in GAP_LOSSES:
            raise ValueError(f"gap_loss must be one of {GAP_LOSSES}, got {gap_loss!r}")
        if gap_blend is not None:
            as_blend(gap_blend)  # refuse unknown or malformed settings now, not at the first clip
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
        self.save_hyperparameters()
        n_in = n_inputs(n_channels, norm) + n_channels  # the inputs and the mask
        self.encoder = mlp(tapered(n_in, code, encoder_layers), last_activation=True)
        self.blstm = BLSTM(code, hidden, layers=2, dropout=dropout, stride=stride)
        self.decoder = mlp([2 * hidden] + [width] * (decoder_layers - 1) + [n_channels], last_activation=False)
        torch.nn.init.zeros_(self.decoder[-1].weight)
        torch.nn.init.zeros_(self.decoder[-1].bias)

    def blend(self) -> GapBlend:
        """How this network's fill is blended with interpolation (``blend_gaps``): the ``gap_blend`` stored
        with it when it was chosen (inference only), else ``GAP_BLEND``."""
        stored = self.hparams.get("gap_blend")
        return GAP_BLEND if stored is None else as_blend(stored)

    def interpolate(self, channels: np.ndarray, mask: np.ndarray, fps: float) -> np.ndarray:
        """The interpolation this network corrects: ``channels [T, C]`` (degrees), ``mask [T, C]`` → ``[T, C]``
        (``fill.gap_fill`` with the ``spline_max_s`` it was trained with)."""
        return gap_fill(channels, mask, self.hparams.get("spline_max_s", 0.0) * fps)

    def features(
        self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor, stats: dict[str, torch.Tensor]
    ) -> torch.Tensor:
        """``[B, T, C]`` degrees, ``[B, T, C]`` bool, ``[B, T, 3]`` rad/s → encoder input ``[B, T, F]``
        (``input_features`` with the mask; ``norm="corpus"``: normalised channels, mask, angular velocity)."""
        return self.input_features(filled, angvel, stats, mask)

    def fill(
        self, filled: torch.Tensor, mask: torch.Tensor, decoded: torch.Tensor, scale: torch.Tensor
    ) -> torch.Tensor:
        """Missing samples ← interpolation + decoded correction × channel ``scale``; others unchanged."""
        return torch.where(mask, filled + decoded * scale, filled)

    def forward(
        self,
        filled: torch.Tensor,
        mask: torch.Tensor,
        angvel: torch.Tensor,
        stats: dict[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Sequence mode: ``filled [B, T, C]`` (gaps interpolated, degrees), ``mask [B, T, C]``, ``angvel
        [B, T, 3]`` → ``[B, T, C]`` with the gaps synthesised; ``stats`` as in ``EBF.forward``."""
        stats = self.input_stats(filled, angvel, stats)
        decoded = self.decoder(self.blstm(self.encoder(self.features(filled, mask, angvel, stats))))
        return self.fill(filled, mask, decoded, stats["scale"])

    def predict_batch(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self(batch["filled"], batch["mask"], batch["angvel"], batch if "scale" in batch else None)

    def windowed(self, filled: torch.Tensor, mask: torch.Tensor, angvel: torch.Tensor) -> torch.Tensor:
        stats = self.input_stats(filled, angvel)
        codes = self.encoder(self.features(filled, mask, angvel, stats))
        return self.fill(filled, mask, self.decoder(self.blstm.windowed(codes, self.hparams.half)), stats["scale"])

    def scored(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """The missing samples only (``batch["mask"]``)."""
        return batch["mask"]

    @property
    def loss_in_degrees(self) -> bool:
        return self.hparams.get("gap_loss", "samples") == "samples"

    def loss_terms(self, batch: dict[str, torch.Tensor], pred: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Squared error over the missing samples only (``gap_loss="samples"``, degrees²); ``"relative"``: each
        sample's divided by its gap's mean squared error of the interpolation (``batch["filled"]``) plus
        ``GAP_LOSS_FLOOR_DEG``² (``gap_means``), so that a short gap, whose interpolation is nearly right, weighs
        as much per sample as a long one instead of ~L⁴ times less; ``"rms"``: divided by that error's square
        root plus ``GAP_LOSS_FLOOR_DEG`` (degrees)."""
        sq, mask = (pred - batch["clean"]) ** 2, self.scored(batch)
        kind = self.hparams.get("gap_loss", "samples")
        if kind == "samples":
            return sq, mask
        with torch.no_grad():
            base = gap_means((batch["filled"] - batch["clean"]) ** 2, mask)
        if kind == "rms":
            return sq / (base.sqrt() + GAP_LOSS_FLOOR_DEG), mask
        return sq / (base + GAP_LOSS_FLOOR_DEG**2), mask


def gap_means(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Each sample of ``values [B, T, C]`` where ``mask [B, T, C]`` is True replaced by the mean over its gap (the
    run of True along T it belongs to, per clip and channel); 0 elsewhere."""
    b, t, c = mask.shape
    before = torch.zeros_like(mask[:, :1])
    starts = mask & ~torch.cat([before, mask[:, :-1]], dim=1)
    gap = torch.cumsum(starts, dim=1)  # [B, T, C]: the gap's number (1, 2, ...) in its clip and channel
    row = (torch.arange(b, device=mask.device)[:, None, None] * c + torch.arange(c, device=mask.device)) * (t + 1)
    key = (row + gap)[mask]
    sums = values.new_zeros(b * c * (t + 1)).index_add_(0, key, values[mask])
    counts = values.new_zeros(b * c * (t + 1)).index_add_(0, key, torch.ones_like(values[mask]))
    out = torch.zeros_like(values)
    out[mask] = sums[key] / counts[key]
    return out


@dataclass(frozen=True)
class GapBlend:
    """How ``blend_gaps`` combines EBD's fill with interpolation (module docstring). Times in seconds.

    ``spline_max_s``: gaps up to this long start from the cubic spline, longer ones from linear interpolation.
    ``gate_s``: the network's weight is 0 for gaps up to ``gate_s[0]``, rising linearly to 1 at ``gate_s[1]``.
    ``taper_s``: inside a gap, the weight rises linearly from ``1 / (taper_s·fps)`` next to an observed frame to
    1 at ``taper_s`` from it. ``speed_quantile`` (percent) and ``speed_factor``: the self-check's speed bound per
    channel, in degrees per frame (``speed_factor = inf`` turns the self-check off). ``rehearsals``: stand-in gaps
    per gap for the rehearsal check (``rehearse``; 0: off); a gap goes to the interpolation when its stand-ins'
    error is below ``rehearse_margin`` × the blend's; gaps shorter than ``rehearse_min_s`` are not rehearsed.
    ``rehearse_mix``: instead of that verdict, each gap at least ``gate_s[1]`` long (where the network has its
    full weight) keeps the share of the network's correction to the interpolation that fitted its stand-ins
    best (least squares, clipped to [0, 1]); shorter gaps, whose small correction makes that share noisy, keep
    the verdict. ``rehearse_pool`` (0 … 1; with ``rehearse_mix`` only): the weight of the clip's pooled share
    (least squares over the stand-ins of all those gaps together) against each gap's own, which few stand-ins
    make noisy. ``short_pool``: instead of the verdict, the gaps shorter than ``gate_s[1]`` keep one share per
    clip, fitted (least squares, clipped to [0, 1]) over the stand-ins of all of them together.
    ``rehearse_passes``: the stand-ins are hidden in this many network passes (each gap's i-th stand-in in pass
    i mod passes) instead of all in one, so each pass hides less of the clip than one pass would (the real
    gaps plus fewer stand-ins), at one network pass more each. ``rehearse_shrink`` (with ``rehearse_mix``): each
    gap's fitted share ``s`` is shrunk by its own uncertainty, estimated from the spread of its stand-ins
    (``_shrunk_share``): ``s · max(0, 1 - v / s²)``; a share that few stand-ins barely support goes toward the
    interpolation. ``rehearse_near_s``: gaps up to this long get the stand-ins nearest to them
    (``stand_in_gaps(near_frames=…)``) instead of ones anywhere in the clip; 0: none. ``rehearse_seed``: the seed
    the stand-ins' places are drawn with (a clip's rehearsal is the same every run; another seed, another draw).
    """

    spline_max_s: float = 0.5
    gate_s: tuple[float, float] = (1 / 30, 0.2)
    taper_s: float = 0.2
    speed_quantile: float = 95.0
    speed_factor: float = 1.5
    rehearsals: int = 0
    rehearse_margin: float = 1.0
    rehearse_min_s: float = 0.0
    rehearse_mix: bool = False
    rehearse_pool: float = 0.0
    short_pool: bool = False
    rehearse_passes: int = 1
    rehearse_shrink: bool = False
    rehearse_near_s: float = 0.0
    rehearse_seed: int = 0


#: The shipped setting: the blend chosen on bandai2 fold 1 (``scripts/bench_ebd.py --tune``), and the rehearsal
#: check (4 stand-ins per gap; gaps of at least 0.2 s keep the share of the correction that fits their stand-ins,
#: shorter ones go to interpolation where it beat the blend by 2x there) chosen on fold 1 with the shipped EBD and
#: on unseen 'elderly' clips with an EBD trained without them (``--compare``; README).
GAP_BLEND = GapBlend(rehearsals=4, rehearse_margin=0.5, rehearse_mix=True)


def _whole(name: str) -> Callable[[Any], int]:
    """A converter giving ``value`` as an int if it is a whole number (not a bool), else ValueError naming
    ``name``."""

    def convert(value: Any) -> int:
        if isinstance(value, bool) or not np.isfinite(float(value)) or float(value) != int(float(value)):
            raise ValueError(f"{name} must be a whole number, got {value!r}")
        return int(float(value))

    return convert


def _flag(name: str) -> Callable[[Any], bool]:
    """A converter giving ``value`` as a bool if it is one, or 0 / 1, else ValueError naming ``name``."""

    def convert(value: Any) -> bool:
        if isinstance(value, (bool, np.bool_)) or value in (0, 1):
            return bool(value)
        raise ValueError(f"{name} must be 0 or 1, got {value!r}")

    return convert


def as_blend(settings: Mapping[str, Any]) -> GapBlend:
    """A ``GapBlend`` from its fields as stored in a checkpoint (``gate_s`` as a list); ValueError naming
    what is wrong."""
    try:
        kinds = {
            "gate_s": tuple,
            "rehearsals": _whole("rehearsals"),
            "rehearse_passes": _whole("rehearse_passes"),
            "rehearse_seed": _whole("rehearse_seed"),
            "rehearse_mix": _flag("rehearse_mix"),
            "short_pool": _flag("short_pool"),
            "rehearse_shrink": _flag("rehearse_shrink"),
        }
        blend = GapBlend(**{k: kinds.get(k, float)(v) for k, v in settings.items()})
    except (TypeError, ValueError) as err:
        raise ValueError(f"gap_blend {dict(settings)!r} is not a GapBlend: {err}") from None
    if len(blend.gate_s) != 2:
        raise ValueError(f"gap_blend gate_s must hold two times (s), got {blend.gate_s!r}")
    if (
        blend.rehearsals < 0
        or not blend.rehearse_margin > 0
        or not blend.rehearse_min_s >= 0
        or blend.rehearse_passes < 1
        or not blend.rehearse_near_s >= 0
        or blend.rehearse_seed < 0
    ):
        raise ValueError(
            "gap_blend needs rehearsals >= 0, rehearse_margin > 0, rehearse_min_s >= 0, rehearse_passes >= 1, "
            f"rehearse_near_s >= 0, rehearse_seed >= 0: got {blend}"
        )
    if not 0.0 <= blend.rehearse_pool <= 1.0:
        raise ValueError(f"gap_blend rehearse_pool must be within [0, 1], got {blend.rehearse_pool!r}")
    return blend


def channel_speed(channels: np.ndarray, mask: np.ndarray, quantile: float) -> np.ndarray:
    """Per channel, the ``quantile`` (percent) of ``|x[t+1] - x[t]|`` (degrees per frame, wrapped) over the
    frame pairs where both samples are observed; ``inf`` for a channel with no such pair. ``channels`` and
    ``mask`` ``[T, C]`` → ``[C]``."""
    steps = np.abs(wrap_near(channels[1:], channels[:-1]) - channels[:-1])
    steps[mask[1:] | mask[:-1]] = np.nan
    out = np.full(channels.shape[1], np.inf)
    seen = ~np.isnan(steps).all(axis=0)
    if seen.any():
        out[seen] = np.nanpercentile(steps[:, seen], quantile, axis=0)
    return out


def _cone_excess(fill: np.ndarray, channels: np.ndarray, a: int, b: int, speed: np.ndarray) -> float:
    """How far (degrees, ≤ 0 when nowhere) the fill ``[b - a, C']`` of the gap ``[a, b)`` leaves the values
    reachable from the observed frames ``a - 1`` and ``b`` (``channels [T, C']``) at ``speed [C']`` degrees
    per frame."""
    t = np.arange(a, b)[:, None]
    worst = -np.inf
    if a > 0:
        edge = channels[a - 1]
        worst = max(worst, float((np.abs(wrap_near(fill, edge) - edge) - speed * (t - a + 1)).max()))
    if b < len(channels):
        edge = channels[b]
        worst = max(worst, float((np.abs(wrap_near(fill, edge) - edge) - speed * (b - t)).max()))
    return worst


def blend_gaps(
    channels: np.ndarray,
    mask: np.ndarray,
    net: np.ndarray,
    fps: float,
    blend: GapBlend = GAP_BLEND,
    interpolated: tuple[np.ndarray, np.ndarray] | None = None,
    trusted: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """EBD's output made final (module docstring): ``channels [T, C]`` (degrees; any value where ``mask [T, C]``
    is True), ``net [T, C]`` the network's fill (degrees), ``fps`` frames per second → ``(filled [T, C], number of
    gaps returned to interpolation by the self-check or by ``trusted``)``. Observed samples are returned unchanged;
    each missing sample becomes ``base + w · (net - base)`` with ``w`` the gate × taper weight of its gap and position.
    ``interpolated``: ``(lerp_fill, spline_fill)`` of ``channels`` when the caller has them (tuning), else
    computed here. ``trusted [n_gaps]`` (``gaps`` order; from ``rehearse``): the share of each gap's blend to keep
    (bool or in [0, 1]); 0 / False sends that gap to the interpolation (counted as a fallback).
    ``blend.rehearsals`` is not used here: the rehearsal needs the network
    (``rehearse``, run by ``infer.clean_channels``), and its verdicts come in as ``trusted``."""
    out = np.where(mask, np.nan, channels).astype(np.float64)
    spline_max = blend.spline_max_s * fps
    gaps = gap_list(mask)
    bases = gap_fill(out, mask, spline_max, interpolated)
    check = bool(np.isfinite(blend.speed_factor))
    speed = channel_speed(out, mask, blend.speed_quantile) * blend.speed_factor if check else None
    lo, hi, taper = blend.gate_s[0] * fps, blend.gate_s[1] * fps, max(blend.taper_s * fps, 1.0)
    fallbacks = 0
    for g, (cols, a, b) in enumerate(gaps):
        length = b - a
        base = bases[a:b][:, cols]
        if np.isnan(base).any():  # no observed sample in these channels: only the network has a value
            out[a:b, cols] = net[a:b, cols]
            continue
        share = 1.0 if trusted is None else float(trusted[g])
        if share <= 0.0:
            out[a:b, cols], fallbacks = base, fallbacks + 1
            continue
        gate = float(np.clip((length - lo) / max(hi - lo, 1e-9), 0.0, 1.0))
        t = np.arange(a, b)
        edge = np.minimum(t - a if a > 0 else np.inf, b - 1 - t if b < len(out) else np.inf)
        weight = gate * np.minimum(1.0, (np.minimum(edge, taper) + 1.0) / taper)[:, None]
        fill = base + weight * (wrap_near(net[a:b][:, cols], base) - base)
        if check and (
            _cone_excess(fill, out[:, cols], a, b, speed[cols])
            > max(_cone_excess(base, out[:, cols], a, b, speed[cols]), 0.0) + 1e-6
        ):
            fill, fallbacks = base, fallbacks + 1
        elif share < 1.0:
            fill = base + share * (fill - base)
        out[a:b, cols] = fill
    return out, fallbacks


def stand_in_gaps(
    mask: np.ndarray, count: int, min_frames: float = 0.0, seed: int = 0, near_frames: float = 0.0
) -> tuple[np.ndarray, list[list[tuple[int, int]]]]:
    """Up to ``count`` stand-ins for each gap of ``mask [T, C]`` (``gap_list`` order) of at least ``min_frames``
    frames: the same channels and length, placed at random (``seed``) where those channels are observed over the
    stand-in and one frame on each side, apart from every gap and every other stand-in of any of those channels.
    A gap of at most ``near_frames`` frames gets its stand-ins instead at the places nearest to it (either side,
    nearest first), with at least the gap's length of observed frames between a stand-in and the gap and between
    two of its stand-ins.
    Gaps that touch the clip's ends get none (their interpolation has one side only). Returns ``(stand-in mask
    [T, C], per gap its stand-ins as (first frame, end frame))``."""
    rng = np.random.default_rng(seed)
    fake = np.zeros_like(mask)
    out: list[list[tuple[int, int]]] = []
    n = len(mask)
    taken: dict[int, np.ndarray] = {}  # per channel group (its first channel): frames missing or rehearsed [T]
    for cols, a, b in gap_list(mask):
        length, mine = b - a, []
        busy = taken.setdefault(int(cols[0]), mask[:, cols].any(axis=1))
        if a > 0 and b < n and length >= min_frames and count > 0:
            free = np.concatenate([[0], np.cumsum(~busy)])
            span = length + 2  # the stand-in and its two observed neighbours
            starts = np.flatnonzero(free[span:] - free[:-span] == span) + 1  # stand-in starts s: frames s-1 … s+L
            apart = length + 1  # |s' - s| beyond this: the frames s'-1 … s'+L of another stand-in stay free
            near = length <= near_frames
            if near:
                starts = starts[(starts + 2 * length <= a) | (starts >= b + length)]
                apart = 2 * length
            while len(starts) and len(mine) < count:
                if near:
                    s = int(starts[np.argmin(np.where(starts < a, a - starts - length, starts - b))])
                else:
                    s = int(rng.choice(starts))
                busy[s - 1 : s + length + 1] = True
                fake[s : s + length, cols] = True
                mine.append((s, s + length))
                starts = starts[np.abs(starts - s) > apart]
        out.append(mine)
    return fake, out


def rehearse(
    channels: np.ndarray,
    mask: np.ndarray,
    fps: float,
    blend: GapBlend,
    network: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """The rehearsal check: how much of the network's blend each gap of ``mask [T, C]`` keeps (``[n_gaps]`` in
    [0, 1], ``gap_list`` order). Each gap gets ``blend.rehearsals`` stand-ins (``stand_in_gaps``) where the
    truth is the observed ``channels [T, C]`` (degrees); ``network(mask [T, C]) -> [T, C]`` fills the clip with
    the real and the stand-in gaps missing. A gap keeps all of the blend (``blend_gaps``, self-check included)
    unless over its stand-ins the squared error of the interpolation it would fall back to is below
    ``blend.rehearse_margin`` × the blend's (then none); with ``blend.rehearse_mix`` a gap at least
    ``blend.gate_s[1]`` long keeps instead the least-squares share of the blend's correction to the
    interpolation on its stand-ins (all of it when the blend did not move the stand-ins at all), mixed with
    weight ``blend.rehearse_pool`` with the share fitted to the stand-ins of all those gaps together (each gap's own
    share shrunk by its stand-ins' spread first with ``blend.rehearse_shrink``, ``_shrunk_share``); with
    ``blend.short_pool`` the shorter gaps keep instead the share fitted to the stand-ins of all of them together.
    Gaps without a stand-in keep it all (nothing to judge by)."""
    gaps = gap_list(mask)
    keep = np.ones(len(gaps))
    if blend.rehearsals <= 0:
        return keep
    fake, stand_ins = stand_in_gaps(
        mask, blend.rehearsals, blend.rehearse_min_s * fps, blend.rehearse_seed, blend.rehearse_near_s * fps
    )
    if not fake.any():
        return keep
    passes = max(1, min(blend.rehearse_passes, max(map(len, stand_ins))))  # a pass with no stand-in is idle
    trials = []  # per pass: (the interpolation, the blend) with the real gaps and that pass's stand-ins missing
    for k in range(passes):
        both = mask | _stand_in_mask(mask, gaps, stand_ins, k, passes)
        trial = np.where(both, np.nan, channels)
        base = gap_fill(trial, both, blend.spline_max_s * fps)
        trials.append((base, blend_gaps(trial, both, network(both), fps, replace(blend, rehearsals=0))[0]))
    fits: dict[int, tuple[float, float]] = {}  # mix-eligible gap -> (step · residual, step²) over its stand-ins
    short: dict[int, tuple[float, float]] = {}  # with short_pool, the same for each shorter gap
    own: dict[int, float] = {}  # mix-eligible gap -> its own share
    for g, ((cols, a, b), places) in enumerate(zip(gaps, stand_ins)):
        if places:
            pieces = [(i % passes, np.arange(s, e)) for i, (s, e) in enumerate(places)]
            truth = np.concatenate([channels[rows][:, cols] for _, rows in pieces])
            base_s = np.concatenate([trials[k][0][rows][:, cols] for k, rows in pieces])
            fill_s = np.concatenate([trials[k][1][rows][:, cols] for k, rows in pieces])
            long_gap = b - a >= blend.gate_s[1] * fps
            if (blend.rehearse_mix and long_gap) or (blend.short_pool and not long_gap):
                step, resid = wrap_deg(fill_s - base_s), wrap_deg(truth - base_s)
                fit = (float((step * resid).sum()), float((step**2).sum()))
                (fits if long_gap else short)[g] = fit
                if long_gap:
                    own[g] = (
                        _shrunk_share(*_per_stand_in(step, resid, pieces)) if blend.rehearse_shrink else _share(*fit)
                    )
                continue
            err = [float((wrap_deg(x - truth) ** 2).sum()) for x in (fill_s, base_s)]
            keep[g] = float(err[1] >= blend.rehearse_margin * err[0])
    if fits:
        pooled = _share(*np.sum(list(fits.values()), axis=0))
        for g in fits:
            keep[g] = (1.0 - blend.rehearse_pool) * own[g] + blend.rehearse_pool * pooled
    if short:
        keep[list(short)] = _share(*np.sum(list(short.values()), axis=0))
    return keep


def _stand_in_mask(
    mask: np.ndarray, gaps: list, stand_ins: list[list[tuple[int, int]]], k: int, passes: int
) -> np.ndarray:
    """The stand-in mask ``[T, C]`` of rehearsal pass ``k`` of ``passes``: every gap's stand-ins number k,
    k + passes, … (``stand_in_gaps`` order)."""
    hidden = np.zeros_like(mask)
    for (cols, _, _), places in zip(gaps, stand_ins):
        for s, e in places[k::passes]:
            hidden[s:e, cols] = True
    return hidden


def _share(fit: float, power: float) -> float:
    """Least-squares share ``fit / power`` of a correction (step · residual over step²), clipped to [0, 1]; all
    of it (1) when the correction is zero."""
    return min(max(fit / power, 0.0), 1.0) if power > 0 else 1.0


def _per_stand_in(
    step: np.ndarray, resid: np.ndarray, pieces: list[tuple[int, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """``step`` and ``resid`` ``[R, C']`` (the stand-ins' rows one after another, ``pieces`` order: (pass, rows))
    → per stand-in ``(Σ step · resid, Σ step²)``, each ``[n]``."""
    parts = np.cumsum([len(rows) for _, rows in pieces])[:-1]
    pairs = [((x * r).sum(), (x**2).sum()) for x, r in zip(np.split(step, parts), np.split(resid, parts))]
    fits, powers = np.array(pairs, dtype=np.float64).T
    return fits, powers


def _shrunk_share(fits: np.ndarray, powers: np.ndarray) -> float:
    """The least-squares share of a correction over ``n`` stand-ins (``fits [n]``: step · residual, ``powers [n]``:
    step², each summed over one stand-in), shrunk by its uncertainty: ``s · max(0, 1 - v / s²)`` clipped to [0, 1],
    with ``s = Σ fits / Σ powers`` and ``v = n / (n - 1) · Σ (fits - s · powers)² / (Σ powers)²`` the linearised
    variance of that ratio from the stand-ins' spread (positive-part James-Stein). Fewer than two stand-ins give no
    spread: ``_share`` unchanged."""
    total = float(powers.sum())
    if len(fits) < 2 or total <= 0:
        return _share(float(fits.sum()), total)
    s = float(fits.sum()) / total
    if s <= 0:
        return 0.0
    n = len(fits)
    v = n / (n - 1) * float(((fits - s * powers) ** 2).sum()) / total**2
    return min(max(s * (1.0 - v / s**2), 0.0), 1.0)
