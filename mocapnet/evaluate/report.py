"""Summaries of evaluation rows: console/markdown tables with ratios, report sections, CSV, and per-motion
error plots. Generic results-file helpers (``fmt``, ``markdown_table``, JSON dumps) are in ``results``."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

from mocapnet.evaluate.harness import ROW_FIELDS, Evaluation, reference
from mocapnet.evaluate.results import fmt, markdown_table, ratio_bars, save_figure, text_output
from mocapnet.methods.registry import MethodSpec


def _mean(values: list[float]) -> float:
    arr = np.asarray(values, dtype=np.float64)
    return float(np.nanmean(arr)) if np.isfinite(arr).any() else float("nan")


def summarize(ev: Evaluation) -> list[dict]:
    """One dict per method: means over (file, repeat) rows of each metric, frames/s, and the ratio to the
    best reference baseline of ``harness.reference`` (the three Gaussians for noise; lerp and spline for gaps;
    lerp+Gaussian-58ms for noise+gaps), taken on the headline metric (``ratio_of``)."""
    by_method: dict[str, list[dict]] = {}
    for r in ev.rows:
        by_method.setdefault(r["method"], []).append(r)
    summary = []
    for method in ev.methods:
        rows = by_method.get(method, [])
        if not rows:
            continue
        entry = {"method": method, "n": len(rows)}
        for key in ("angle_err_deg", "gap_err_deg", "rot_err_deg", "pos_err_cm", "point_err_cm"):
            entry[key] = _mean([r[key] for r in rows])
        seconds = sum(r["seconds"] for r in rows)
        entry["frames_per_s"] = sum(r["frames"] for r in rows) / seconds if seconds > 0 else float("inf")
        summary.append(entry)
    metric, reference = headline(ev)
    ref_value = min(
        (e[metric] for e in summary if _base(e["method"]) in reference and math.isfinite(e[metric])),
        default=math.nan,
    )
    for e in summary:
        e["ratio"] = e[metric] / ref_value if ref_value and math.isfinite(ref_value) else float("nan")
        e["ratio_of"] = metric
    return summary


def _base(method: str) -> str:
    """A method's registered name (``gaussian-tuned:tune_on=bandai2`` → ``gaussian-tuned``)."""
    return MethodSpec.parse(method).name


def headline(ev: Evaluation) -> tuple[str, tuple[str, ...]]:
    """(metric, reference methods) for the ratio column: ``harness.reference``, the one rule."""
    ref = reference(ev.corruption, ev.space)
    return ref.metric, ref.methods


def table(ev: Evaluation, markdown: bool = False) -> str:
    """The summary table as aligned text (console) or markdown."""
    summary = summarize(ev)
    metric, reference = headline(ev)
    if ev.space == "points":
        cols = [
            ("method", "method"),
            ("point_err_cm", "point err cm"),
            ("ratio", "ratio"),
            ("frames_per_s", "frames/s"),
            ("n", "n"),
        ]
    else:
        cols = [
            ("method", "method"),
            ("angle_err_deg", "angle err °"),
            ("gap_err_deg", "gap err °"),
            ("rot_err_deg", "rot err °"),
            ("pos_err_cm", "pos err cm"),
            ("ratio", "ratio"),
            ("frames_per_s", "frames/s"),
            ("n", "n"),
        ]
    body = []
    for e in summary:
        row = []
        for key, _ in cols:
            v = e[key]
            row.append(v if isinstance(v, str) else str(v) if key == "n" else fmt(v, 0 if key == "frames_per_s" else 3))
        body.append(row)
    head = [c[1] for c in cols]
    present = [e["method"] for e in summary if _base(e["method"]) in reference]
    note = f"ratio = {metric} ÷ that of the best of {', '.join(present) or reference[0]}"
    if markdown:
        return "\n".join(markdown_table(head, body)) + f"\n\n{note}"
    widths = [max([len(h)] + [len(r[i]) for r in body]) for i, h in enumerate(head)]
    fmt_row = lambda r: "  ".join(v.ljust(w) if i == 0 else v.rjust(w) for i, (v, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([fmt_row(head), fmt_row(["-" * w for w in widths])] + [fmt_row(r) for r in body] + [note])


def evaluation_section(ev: Evaluation, plot: str | os.PathLike | None = None) -> list[str]:
    """Markdown lines for one (data, corruption) of a report: a heading with the clip count, the table with
    ratios, the per-motion error plot (written to ``plot`` when given and linked by its name) and the skipped
    clips with their reasons."""
    lines = ["", f"## {ev.data}: {ev.corruption} ({len({r['file'] for r in ev.rows})} clips)", "", table(ev, True)]
    if plot is not None:
        plot_per_motion(ev, plot, title=f"{ev.data}: {ev.corruption}")
        lines += ["", f"![error per motion]({Path(plot).name})"]
    return lines + [f"- skipped {name}: {reason}" for name, reason in ev.skipped]


def write_csv(path: str | os.PathLike, rows: list[dict]) -> None:
    """One line per (method, corruption, file, repeat) with the columns of ``ROW_FIELDS``; gzip-compressed
    (reproducibly: no name or time in the header) when ``path`` ends in ``.gz``."""
    with text_output(path, newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(ROW_FIELDS))
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in ROW_FIELDS})


def plot_per_motion(ev: Evaluation, path: str | os.PathLike, title: str = "") -> None:
    """Error per motion (mean over repeats) for each method, motions sorted by the first method's error —
    the layout of the EBF paper's Figures 5 and 9."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric, _ = headline(ev)
    per: dict[str, dict[str, list[float]]] = {}
    for r in ev.rows:
        per.setdefault(r["method"], {}).setdefault(r["file"], []).append(r[metric])
    shown = [m for m in ev.methods if np.isfinite([_mean(v) for v in per.get(m, {}).values()] or [np.nan]).any()]
    key = shown[0]
    files = sorted(per[key], key=lambda f: _mean(per[key][f]))
    unit = "cm" if metric.endswith("cm") else "degrees"
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if len(files) <= 3:  # too few motions for a curve: one bar per method, a dot per clip and repeat
        for i, method in enumerate(shown):
            values = [v for f in files for v in per[method].get(f, [])]
            ax.bar(i, _mean(values), color=f"C{i}", alpha=0.6)
            ax.plot([i] * len(values), values, "k.", ms=4)
        ax.set_xticks(range(len(shown)), shown, rotation=20, ha="right", fontsize=8)
    elif len(files) <= 60:
        for method in shown:
            ys = [_mean(per[method].get(f, [math.nan])) for f in files]
            ax.plot(range(len(files)), ys, ".-", lw=1, ms=3, label=method)
        ax.set_xlabel(f"motion (sorted by {key} error), {len(files)} clips")
        ax.legend(fontsize=8)
    else:  # many motions: each method's per-motion errors sorted on their own (a readable distribution)
        for method in shown:
            ys = np.sort([_mean(v) for v in per[method].values()])
            ax.plot(np.linspace(0, 100, len(ys)), ys, lw=1.2, label=f"{method} (median {np.nanmedian(ys):.2f})")
        ax.set_xlabel(f"percent of motions ({len(files)} clips), each method sorted by its own error")
        ax.legend(fontsize=8)
    ax.set_ylabel(f"{metric.replace('_', ' ')} ({unit})")
    ax.set_title(title or f"{ev.data}: {ev.corruption}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def _drawn_as(method: str, wanted: list[str], rows: list[dict]) -> str:
    """The name of ``wanted`` a results row of ``method`` is drawn under: its own, or its method name without the
    checkpoint and options (``ebf-paper=run.ckpt`` as ``ebf-paper``) when no row of ``rows`` (one corpus's) has
    that name exactly and only one method string of them has that base; else ``method`` itself (not drawn)."""
    if method in wanted:
        return method
    base = MethodSpec.parse(method).name
    if base in wanted and not any(r["method"] == base for r in rows):
        same = {r["method"] for r in rows if MethodSpec.parse(r["method"]).name == base}
        if len(same) > 1:
            raise ValueError(f"{base}: several method strings in the results ({sorted(same)}): name one exactly")
        return base
    return method


def plot_ratios(rows: list[dict], methods: list[str], path: str | os.PathLike, title: str = "") -> None:
    """The ratio column of ``bench_neural`` results (each row a summary with ``corpus``, ``corruption``,
    ``method``, ``ratio``) as a PNG: one panel per corpus, one group of bars per corruption, one bar per method
    of ``methods`` found (a vertical line at 1: the best reference baseline); a method with several rows for one
    corpus and corruption is drawn from the first; a name matches a method string with a checkpoint when that
    string is the only one of its name (``_drawn_as``). Corruptions without a ratio (clean input) are left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratio: dict[tuple[str, str, str], float] = {}
    for r in rows:  # a method scored in several files: the first row counts
        same_corpus = [q for q in rows if q["corpus"] == r["corpus"]]
        ratio.setdefault((r["corpus"], r["corruption"], _drawn_as(r["method"], methods, same_corpus)), r["ratio"])
    corpora = list(dict.fromkeys(r["corpus"] for r in rows))
    found = [m for m in methods if any(k[2] == m for k in ratio)]
    if not found:
        raise ValueError(f"none of {methods} is in the results (methods there: {sorted({k[2] for k in ratio})})")
    panels = []
    for corpus in corpora:
        corruptions = [
            c
            for c in dict.fromkeys(r["corruption"] for r in rows if r["corpus"] == corpus)
            if any(np.isfinite(ratio.get((corpus, c, m), np.nan)) for m in found)
        ]
        panels.append((corpus, corruptions))
    n_rows = max(len(c) for _, c in panels)
    fig, axes = plt.subplots(
        1, len(panels), figsize=(4.6 * len(panels), 0.42 * n_rows * len(found) / 2 + 1.8), sharex=True
    )
    for ax, (corpus, corruptions) in zip(np.atleast_1d(axes), panels):
        series = {m: [ratio.get((corpus, c, m), np.nan) for c in corruptions] for m in found}
        ratio_bars(ax, corruptions, series, value_size=6)
        ax.set_title(corpus, fontsize=10)
        ax.set_xlabel("error ÷ the best reference baseline", fontsize=8)
    np.atleast_1d(axes)[-1].legend(loc="lower right", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
