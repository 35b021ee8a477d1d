"""Gap filling scored gap by gap (issue 11): RMS error per gap-length bin against lerp and spline, and the
score that chose EBD's blend with interpolation (``mocapnet.nn.ebd.GAP_BLEND``) on bandai2 fold 1.

A gap is one run of missing frames of the scored channels that share one missing pattern (``fill.mask_groups``:
one joint, or every joint of a segment missing together); its error is taken over those channels. Clips are
corrupted with the protocol's seeds (``corrupt.seed_for``), as ``harness.evaluate_angles`` does, so the headline
figures here equal the harness's ``gap_err_deg``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from mocapnet.corpus import load_corpus
from mocapnet.corrupt import corrupt_motion, seed_for
from mocapnet.evaluate.metrics import gap_err_deg, wrapped_diff
from mocapnet.evaluate.results import markdown_table, ratio_bars, save_figure
from mocapnet.fill import gap_list
from mocapnet.motion import Motion

#: Gap-length bins in frames, inclusive (issue 11: ≤ 5, 5–15, 15–30, 30–60, > 60).
GAP_BINS = ((1, 5), (6, 15), (16, 30), (31, 60), (61, 10**9))
BIN_LABELS = ("≤ 5", "6–15", "16–30", "31–60", "> 60")
#: The interpolations every gap filler has to beat.
REFERENCES = ("lerp", "spline")
#: The corruptions of the issue's done-when (``test``) and those the blend was tuned on (``tune``).
TEST = ("gaps", "gaps-long", "segment-gap:left-arm:0.5", "segment-gap:left-arm:2")
TUNE = (*TEST, "segment-gap:right-leg:1")
OFF = float("inf")


@dataclass
class FilledClip:
    """One corrupted clip: the scored channels ``truth [T, C_s]`` (degrees), ``mask [T, C_s]`` (True =
    missing), the frame rate, and each filler's output ``[T, C_s]`` by name."""

    name: str
    truth: np.ndarray
    mask: np.ndarray
    fps: float
    outputs: dict[str, np.ndarray] = field(default_factory=dict)


def subset(clips: list[Motion], n: int | None) -> list[Motion]:
    """``n`` clips evenly spaced over ``clips`` (the fold's order is stratified by content), or all."""
    return clips if not n or n >= len(clips) else clips[:: len(clips) // n][:n]


def fill_clips(
    corpus: str,
    clips: Sequence[Motion],
    corruption: str,
    repeats: int,
    fillers: Mapping[str, Callable[[Motion, np.ndarray], np.ndarray]],
) -> list[FilledClip]:
    """Corrupt each clip ``repeats`` times (protocol seeds of ``corpus``; clips too short for the corruption
    are left out) and fill it with every ``fillers[name](noisy motion, mask [T, C]) -> [T, C]``; only the
    scored channels are kept. Clips without a missing sample are left out (no gap error)."""
    out = []
    for motion in clips:
        scored = motion.skeleton.scored_mask
        for rep in range(repeats):
            rng = np.random.default_rng(seed_for(corpus, motion.name, rep, corruption))
            try:
                noisy, mask = corrupt_motion(motion, corruption, rng)
            except ValueError:
                break
            if not mask[:, scored].any():
                continue
            noisy_motion = motion.with_channels(noisy)
            outputs = {name: fill(noisy_motion, mask)[:, scored] for name, fill in fillers.items()}
            out.append(FilledClip(motion.name, motion.channels[:, scored], mask[:, scored], motion.fps, outputs))
    return out


def headline(items: Iterable[FilledClip], name: str) -> float:
    """Mean over clips of each clip's RMS gap error (degrees): the harness's ``gap_err_deg`` headline."""
    return float(np.mean([gap_err_deg(it.outputs[name], it.truth, it.mask) for it in items]))


def bin_errors(items: Sequence[FilledClip], names: Sequence[str]) -> list[dict]:
    """Per gap-length bin: ``{"bin", "gaps", name: RMS degrees (NaN without gaps), ...}`` pooled over every
    gap of ``items``."""
    sse = np.zeros((len(names), len(GAP_BINS)))
    count = np.zeros(len(GAP_BINS))
    gaps = np.zeros(len(GAP_BINS), dtype=int)
    for it in items:
        for cols, a, b in gap_list(it.mask):
            k = next(i for i, (lo, hi) in enumerate(GAP_BINS) if lo <= b - a <= hi)
            gaps[k] += 1
            count[k] += (b - a) * len(cols)
            truth = it.truth[a:b, cols]
            for m, name in enumerate(names):
                sse[m, k] += float((wrapped_diff(it.outputs[name][a:b, cols], truth) ** 2).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sse / count)
    return [
        {"bin": BIN_LABELS[k], "gaps": int(gaps[k]), **{n: float(rms[m, k]) for m, n in enumerate(names)}}
        for k in range(len(GAP_BINS))
    ]


def ratios(filled: Mapping[str, Sequence[FilledClip]], name: str) -> dict[str, float]:
    """The selection score's ratios of ``name``: per corruption its headline ÷ the better of lerp's and
    spline's, and per gap-length bin (gaps of every corruption pooled) its RMS ÷ the better of theirs. A
    corruption or bin that both references fill exactly (hidden channels that never move) has no ratio, unless
    ``name`` misses it (then inf)."""
    out = {}
    for c, items in filled.items():
        if items:
            out[c] = _ratio(headline(items, name), min(headline(items, r) for r in REFERENCES))
    for row in bin_errors([it for items in filled.values() for it in items], [name, *REFERENCES]):
        if row["gaps"]:
            out[f"bin {row['bin']}"] = _ratio(row[name], min(row[r] for r in REFERENCES))
    return {k: v for k, v in out.items() if not np.isnan(v)}


def _ratio(error: float, best: float) -> float:
    """``error / best``; where the references are exact (``best`` 0) NaN (no ratio) if ``error`` is 0 too, else
    inf (a candidate that misses what interpolation gets exactly is not let off)."""
    if best > 0:
        return error / best
    return float("nan") if error == 0 else float("inf")


def select(scores: Mapping[str, Mapping[str, float]], tie: float = 0.005) -> str:
    """The pre-written selection rule: the candidate with the smallest worst ratio; candidates within ``tie``
    of that are ranked by their mean ratio."""
    worst = {k: max(v.values()) for k, v in scores.items()}
    best = min(worst.values())
    return min((k for k in scores if worst[k] <= best + tie), key=lambda k: float(np.mean(list(scores[k].values()))))


def candidates(grid: str = "around") -> dict:
    """Blend settings scored by ``tune``. ``grid="around"``: one parameter at a time around the shipped
    ``GAP_BLEND`` without its rehearsal ("shipped" is that blend alone); ``"gates"``: longer length gates
    (0.3–0.5 s) with a spline base up to 0.25 or 0.5 s. "no check" (self-check off) is the self-check's baseline in
    both."""
    from mocapnet.nn.ebd import GAP_BLEND

    alone = dataclasses.replace(GAP_BLEND, rehearsals=0)  # tune scores blend_gaps without the rehearsal

    if grid == "gates":
        gates = ((1 / 30, 0.3), (1 / 30, 0.4), (0.1, 0.4), (0.1, 0.5))
        return {
            **{
                f"gate {lo:.3g}-{hi:g} s, spline <= {sm:g} s": dataclasses.replace(
                    alone, gate_s=(lo, hi), spline_max_s=sm
                )
                for lo, hi in gates
                for sm in (0.25, 0.5)
            },
            "shipped": alone,
            "no check": dataclasses.replace(alone, speed_factor=OFF),
        }
    if grid != "around":
        raise ValueError(f"grid must be 'around' or 'gates', got {grid!r}")
    return {
        "shipped": alone,
        "no check": dataclasses.replace(alone, speed_factor=OFF),
        "no taper": dataclasses.replace(alone, taper_s=0.0),
        "no gate": dataclasses.replace(alone, gate_s=(0.0, 0.0)),
        "no gate or taper": dataclasses.replace(alone, gate_s=(0.0, 0.0), taper_s=0.0),
        "gate to 0.1 s": dataclasses.replace(alone, gate_s=(alone.gate_s[0], 0.1)),
        "taper 0.1 s": dataclasses.replace(alone, taper_s=0.1),
        "lerp base": dataclasses.replace(alone, spline_max_s=0.0),
        "spline <= 0.25 s": dataclasses.replace(alone, spline_max_s=0.25),
        **{f"check x{f:g}": dataclasses.replace(alone, speed_factor=f) for f in (1.0, 2.0, 3.0)},
        "check q99": dataclasses.replace(alone, speed_quantile=99.0),
        "check q100": dataclasses.replace(alone, speed_quantile=100.0),
    }


def raw_filler(checkpoint: str | None = None) -> Callable[[Motion, np.ndarray], np.ndarray]:
    """EBD's fill as it comes (no blend; ``methods.neural.ebd_raw_filler``): ``checkpoint`` as ``PATH[:OPTIONS]``
    (the network alone, or with the one its ``short=PATH`` names), by default the shipped ``ebd`` of each clip's
    skeleton with its short-gap network."""
    from mocapnet.methods.neural import ebd_raw_filler
    from mocapnet.methods.registry import MethodSpec

    if checkpoint is None:
        return ebd_raw_filler()
    spec = MethodSpec.parse(f"ebd={checkpoint}")
    return ebd_raw_filler(spec.checkpoints[0], spec.options.get("short", "auto"), spec.options.get("short_max_s"))


def tune(repeats: int, checkpoint: str | None = None, grid: str = "around") -> dict:
    """Score ``candidates(grid)`` and the raw network (``checkpoint``, default the shipped EBD) on bandai2 fold 1
    (``ratios``): the blend geometry selected by ``select`` and the self-check by the most fallbacks within
    0.5 % of the mean ratio without it."""
    from mocapnet.methods.registry import build_method
    from mocapnet.nn.ebd import blend_gaps

    clips = load_corpus("bandai2", progress=False).split(0)[1]
    fillers = {n: build_method(n).clean for n in REFERENCES} | {"ebd-raw": raw_filler(checkpoint)}
    filled = {c: fill_clips("bandai2", clips, c, repeats, fillers) for c in TUNE}
    scores, fallbacks = {"ebd-raw": ratios(filled, "ebd-raw")}, {}
    for label, blend in candidates(grid).items():
        fallbacks[label] = 0
        for it in (it for items in filled.values() for it in items):
            o = it.outputs
            out, n = blend_gaps(o["lerp"], it.mask, o["ebd-raw"], it.fps, blend, (o["lerp"], o["spline"]))
            it.outputs[label], fallbacks[label] = out, fallbacks[label] + n
        scores[label] = ratios(filled, label)
        for it in (it for items in filled.values() for it in items):
            del it.outputs[label]
        print(label, f"worst {max(scores[label].values()):.3f}", f"fallbacks {fallbacks[label]}", flush=True)
    return {"scores": scores, "fallbacks": fallbacks, **choose(scores, fallbacks)}


def choose(scores: Mapping[str, Mapping[str, float]], fallbacks: Mapping[str, int]) -> dict[str, str]:
    """The pre-written rules applied to ``tune``'s scores: the blend geometry by ``select`` among "shipped", the
    geometry candidates (all with the shipped self-check; "no gate or taper" is the network's own fill) — not
    "ebd-raw", which has no self-check and so is no storable setting; the self-check by
    the most fallbacks among the "check" candidates and "shipped" whose mean ratio is within 0.5 % of "no
    check"'s."""
    mean = {k: float(np.mean(list(v.values()))) for k, v in scores.items()}
    checks = [k for k in scores if k.startswith("check") or k == "shipped"]
    check = max((k for k in checks if mean[k] <= 1.005 * mean["no check"]), key=fallbacks.get, default="no check")
    geometry = {k: v for k, v in scores.items() if k == "shipped" or k not in (*checks, "no check", "ebd-raw")}
    return {"selected": select(geometry), "check": check}


def compare(corpus: str, clips: Sequence[Motion], checkpoints: Mapping[str, str], repeats: int) -> dict:
    """EBD networks side by side on ``clips`` of ``corpus`` (a selection set: fold 1 or an unseen style), each
    ``PATH[:OPTIONS]`` as ``ebd=PATH[:OPTIONS]`` (the checkpoint's blend and self-check unless an option changes
    it) and, without options, raw: ``ratios`` over ``TUNE`` per label (``LABEL`` and ``LABEL raw``),
    ``select``'s choice among the blended ones, and the headline gap errors."""
    from mocapnet.methods.registry import build_method

    fillers = {n: build_method(n).clean for n in REFERENCES}
    for label, spec in checkpoints.items():
        fillers[label] = build_method(f"ebd={spec}").clean
        if ":" not in spec or ":short=" in spec or ",short=" in spec:  # blend options leave the raw fill as it is
            fillers[f"{label} raw"] = raw_filler(spec)
    filled = {}
    for c in TUNE:
        filled[c] = fill_clips(corpus, clips, c, repeats, fillers)
        print(corpus, c, {n: round(headline(filled[c], n), 3) for n in fillers}, flush=True)
    scores = {n: ratios(filled, n) for n in fillers if n not in REFERENCES}
    errors = {c: {n: headline(items, n) for n in fillers} for c, items in filled.items()}
    n_clips = len({it.name for items in filled.values() for it in items})
    return {
        "scores": scores,
        "errors": errors,
        "selected": select({k: scores[k] for k in checkpoints}),
        "clips": n_clips,
        "repeats": repeats,
        "checkpoints": dict(checkpoints),
    }


def compare_markdown(result: dict) -> str:
    """``compare``'s result as Markdown tables."""
    lines = [f"# EBD networks on {result['split']} ({result['clips']} clips × {result['repeats']} repeats)\n"]
    lines += [
        f"Command: `{result['command']}`; selected (smallest worst ratio of the blended ones): {result['selected']}\n",
        "Ratio to the better of lerp and spline:\n",
    ]
    cols = list(next(iter(result["scores"].values())))
    rows = []
    for k, v in result["scores"].items():
        rows.append([k, f"{max(v.values()):.3f}", f"{np.mean(list(v.values())):.3f}", *(f"{v[c]:.3f}" for c in cols)])
    lines += markdown_table(["network", "worst", "mean", *cols], rows)
    names = list(next(iter(result["errors"].values())))
    lines += ["", "Gap error (°, mean over clips of each clip's RMS):", ""]
    lines += markdown_table(
        ["corruption", *names], ([c, *(f"{e[n]:.3f}" for n in names)] for c, e in result["errors"].items())
    )
    lines += ["", "Checkpoints: " + "; ".join(f"{k} = `{v}`" for k, v in result["checkpoints"].items())]
    return "\n".join(lines) + "\n"


def test(corpus: str, n_clips: int | None, repeats: int, checkpoint: str | None = None) -> dict:
    """lerp, spline, the raw network and ``ebd`` (``checkpoint``, default the shipped EBD) on ``n_clips`` evenly
    spaced fold-0 clips (default all): headline gap errors per corruption of ``TEST`` and RMS per gap-length
    bin."""
    from mocapnet.methods.registry import build_method

    clips = subset(load_corpus(corpus, progress=False).split(0)[2], n_clips)
    ebd = "ebd" if checkpoint is None else f"ebd={checkpoint}"
    fillers = {n: build_method(n).clean for n in REFERENCES} | {"ebd": build_method(ebd).clean}
    fillers["ebd-raw"] = raw_filler(checkpoint)
    names = [*REFERENCES, "ebd-raw", "ebd"]
    rows, bins = [], []
    for c in TEST:
        items = fill_clips(corpus, clips, c, repeats, fillers)
        rows.append({"corruption": c, "clips": len({it.name for it in items}), "repeats": repeats})
        rows[-1] |= {n: headline(items, n) for n in names}
        bins += [{"corruption": c, **b} for b in bin_errors(items, names) if b["gaps"]]
        print(corpus, c, {n: round(rows[-1][n], 3) for n in names}, flush=True)
    return {"corpus": corpus, "headline": rows, "bins": bins, "names": names}


def markdown(result: dict) -> str:
    """``test``'s result as Markdown tables."""
    names = result["names"]

    def scores(r: dict) -> list[str]:  # each filler's error, then ebd's ratio to the better reference
        return [*(f"{r[n]:.3f}" for n in names), f"{r['ebd'] / min(r[n] for n in REFERENCES):.3f}"]

    lines = [f"# EBD gap filling, {result['corpus']} fold 0\n", f"Command: `{result['command']}`\n"]
    lines += markdown_table(
        ["corruption", "clips × repeats", *names, "ebd ÷ best of lerp, spline"],
        ([r["corruption"], f"{r['clips']} × {r['repeats']}", *scores(r)] for r in result["headline"]),
    )
    lines += ["", "RMS gap error (°) per gap length in frames:", ""]
    lines += markdown_table(
        ["corruption", "bin", "gaps", *names, "ebd ÷ best"],
        ([b["corruption"], b["bin"], b["gaps"], *scores(b)] for b in result["bins"]),
    )
    return "\n".join(lines) + "\n"


def plot(result: dict, path: str | os.PathLike) -> None:
    """``test``'s result as a PNG at ``path``: per corruption and per gap-length bin, the gap error of ``ebd`` and
    of ``ebd-raw`` divided by the better of lerp and spline (bars; left of the line at 1 beats both)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [(r["corruption"], r) for r in result["headline"]]
    rows += [(f"{b['corruption']}  {b['bin']} frames ({b['gaps']} gaps)", b) for b in result["bins"]]
    learned = [n for n in ("ebd", "ebd-raw") if n in result["names"]]
    ratios = {n: [r[n] / min(r[m] for m in REFERENCES) for _, r in rows] for n in learned}
    fig, ax = plt.subplots(figsize=(8.5, 0.38 * len(rows) + 1.6))
    ratio_bars(ax, [label for label, _ in rows], ratios)
    ax.set_xlabel("gap error ÷ the better of lerp and spline (< 1: better than both)")
    ax.set_title(f"EBD gap filling, {result['corpus']} fold 0", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def tune_markdown(result: dict) -> str:
    """``tune``'s result as a Markdown table."""
    cols = list(result["scores"]["shipped"])
    lines = ["# EBD blend settings on bandai2 fold 1 (ratio to the better of lerp and spline)\n"]
    lines += [f"Command: `{result['command']}`; selected blend: {result['selected']}; self-check: {result['check']}\n"]
    rows = []
    for k, v in result["scores"].items():
        worst, mean = max(v.values()), np.mean(list(v.values()))
        vals = (f"{v.get(c, float('nan')):.3f}" for c in cols)
        rows.append([k, result["fallbacks"].get(k, "—"), f"{worst:.3f}", f"{mean:.3f}", *vals])
    lines += markdown_table(["setting", "fallbacks", "worst", "mean", *cols], rows)
    return "\n".join(lines) + "\n"
