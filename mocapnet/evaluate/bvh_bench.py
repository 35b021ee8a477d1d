"""BVH loading CPU time of ``read_bvh`` vs the PyPI ``bvh`` package (the reference), for
``scripts/bench_bvh_io.py``.

Per file the readers run back to back in an order that rotates from file to file (interleaved), each timed
with ``time.process_time`` (CPU time of this process: other jobs on a shared machine count less), over several
rounds. "text": both parse the same decompressed text already in memory into a float array ``[T, C]`` plus the
joint names, mocapnet with ``read_bvh``'s defaults (every check, unit guess, unwrapping), also with its
hierarchy cache cleared before every file and, given a commit, as the reader of that commit. "file":
``read_bvh(path)`` vs ``gzip`` + the package on the same ``.bvh.gz`` file.
"""

from __future__ import annotations

import gzip
import os
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import markdown_table
from mocapnet.io import bvh as bvh_module
from mocapnet.io.bvh import format_bvh, parse_bvh, read_bvh
from mocapnet.motion import Motion, Skeleton

PACKAGE = "bvh package"


def read_with_bvh_package(text: str) -> tuple[np.ndarray, list[str]]:
    """Frames ``[T, C]`` and joint names with the PyPI ``bvh`` package (test extra)."""
    from bvh import Bvh

    mocap = Bvh(text)
    return np.array(mocap.frames, dtype=np.float64), mocap.get_joints_names()


def interleaved(readers: dict[str, Callable[[Any], object]], items: Sequence, rounds: int) -> dict[str, float]:
    """Total CPU seconds of each reader over ``items`` and ``rounds``; per item the readers run back to back,
    in an order that rotates from item to item."""
    names = list(readers)
    totals = dict.fromkeys(names, 0.0)
    for r in range(rounds):
        for i, item in enumerate(items):
            shift = (i + r) % len(names)
            for name in names[shift:] + names[:shift]:
                t0 = time.process_time()
                readers[name](item)
                totals[name] += time.process_time() - t0
    return totals


def previous_reader(commit: str) -> ModuleType:
    """``mocapnet/io/bvh.py`` as it was at ``commit`` (git), imported as a module for a same-run baseline."""
    source = subprocess.run(
        ["git", "show", f"{commit}:mocapnet/io/bvh.py"], cwd=REPO, check=True, capture_output=True, text=True
    ).stdout
    module = ModuleType(f"bvh_at_{commit}")
    exec(compile(source, f"bvh.py@{commit}", "exec"), module.__dict__)  # noqa: S102 - our own file from git
    return module


def _parse_without_cache(item: tuple[str, Path]) -> None:
    bvh_module._HIERARCHY_CACHE.clear()
    parse_bvh(*item)


def bench_corpus(files: Sequence[Path], rounds: int, baseline: ModuleType | None = None, label: str = "") -> dict:
    """CPU seconds and speed-ups vs the package of every reader on ``files`` (text and file), the largest
    value difference to the package (mocapnet without unwrapping) and the load average around the run."""
    load = os.getloadavg()[0]
    texts = [gzip.open(f, "rb").read().decode() for f in files]
    max_diff, frames = 0.0, 0
    for text, f in zip(texts, files):
        m = parse_bvh(text, f, unwrap=False)
        values, names = read_with_bvh_package(text)
        if list(m.skeleton.names) != names:
            raise AssertionError(f"{f}: joint names differ from the bvh package's")
        max_diff, frames = max(max_diff, float(np.abs(m.channels - values).max())), frames + m.n_frames
    readers: dict[str, Callable] = {
        "mocapnet": lambda it: parse_bvh(*it),
        PACKAGE: lambda it: read_with_bvh_package(it[0]),
        "mocapnet, no hierarchy cache": _parse_without_cache,
    }
    if baseline is not None:
        readers[f"mocapnet at {label}"] = lambda it: baseline.parse_bvh(*it)
    text = interleaved(readers, list(zip(texts, files)), rounds)
    file = interleaved(
        {"mocapnet": read_bvh, PACKAGE: lambda f: read_with_bvh_package(gzip.open(f, "rb").read().decode())},
        files,
        rounds,
    )
    return {
        "files": len(files),
        "frames": frames,
        "rounds": rounds,
        "load_average": [load, os.getloadavg()[0]],
        "text_cpu_s": text,
        "text_speedup_vs_bvh_package": {k: text[PACKAGE] / v for k, v in text.items()},
        "file_cpu_s": file,
        "file_speedup": file[PACKAGE] / file["mocapnet"],
        "max_abs_diff": max_diff,
    }


def synthetic(n_joints: int, chain: bool, seed: int = 0) -> Motion:
    """A random tree (or a single chain) of ``n_joints`` joints, 3 rotation channels each, an End Site on every
    leaf, 2 frames."""
    rng = np.random.default_rng(seed)
    parents = tuple(j - 1 if chain else int(rng.integers(0, j)) if j else -1 for j in range(n_joints))
    channels = tuple(("Zrotation", "Xrotation", "Yrotation") for _ in range(n_joints))
    leaves = tuple(sorted(set(range(n_joints)) - set(parents)))
    sk = Skeleton(
        tuple(f"j{j}" for j in range(n_joints)),
        parents,
        rng.normal(size=(n_joints, 3)),
        channels,
        rng.normal(size=(len(leaves), 3)),
        leaves,
    )
    return Motion(sk, rng.uniform(-170, 170, (2, sk.n_channels)), 30.0, "synthetic")


def hierarchy_timings(baseline: ModuleType | None = None) -> dict[str, float]:
    """CPU seconds: parse of a 10,000-joint tree with ``read_bvh``'s defaults (unit guess included; also with
    the baseline reader when given); write + read of a 1,000-level chain."""
    text = format_bvh(synthetic(10_000, chain=False))
    timings = {}
    for name, parse in [("mocapnet", parse_bvh)] + ([("baseline", baseline.parse_bvh)] if baseline else []):
        bvh_module._HIERARCHY_CACHE.clear()
        t0 = time.process_time()
        m = parse(text, "tree10k.bvh")
        timings[f"parse_10k_joint_tree_{name}_s"] = time.process_time() - t0
        if m.skeleton.n_joints != 10_000:
            raise AssertionError("the 10k-joint tree did not read back")
    chain = synthetic(1_000, chain=True)
    t0 = time.process_time()
    back = parse_bvh(format_bvh(chain), "chain1000.bvh", cm_per_unit=1.0, unwrap=False)
    timings["write_read_1000_level_chain_s"] = time.process_time() - t0
    if np.abs(back.channels - chain.channels).max() >= 1e-6:
        raise AssertionError("the 1,000-level chain did not read back")
    return timings


def markdown(report: dict) -> str:
    """The results page of ``bench_bvh_io.py``: CPU seconds and speed-ups per corpus and reader."""
    rows = []
    for name, r in report["corpora"].items():
        for reader, seconds in r["text_cpu_s"].items():
            file_s = r["file_cpu_s"].get(reader)
            file_x = {"mocapnet": f"{r['file_speedup']:.1f}×", PACKAGE: "1.0×"}.get(reader, "")
            speedup = f"{r['text_speedup_vs_bvh_package'][reader]:.1f}×"
            load = "{:.1f} → {:.1f}".format(*r["load_average"])
            file_s = "" if file_s is None else f"{file_s:.3f}"
            rows.append((name, r["files"], r["frames"], reader, f"{seconds:.3f}", speedup, file_s, file_x, load))
    h = report["hierarchy"]
    baseline = report.get("baseline")
    return (
        "\n".join(
            [
                "# BVH loading: mocapnet vs the PyPI `bvh` package (CPU time, interleaved)",
                "",
                f"`{report['command']}` at {report['git_commit']}; {report['machine']}.",
                "CPU seconds (`time.process_time`) summed over all files and rounds; per file the readers run back to",
                "back in an order that rotates from file to file. text = both parse the same in-memory text (mocapnet",
                "with `read_bvh`'s defaults: checks, unit guess, unwrapping); file = `read_bvh(path)` vs gzip + the",
                "package on the same `.bvh.gz`. Load average = the machine's 1-minute load before → after the corpus.",
                "",
                *markdown_table(
                    (
                        "corpus",
                        "files",
                        "frames",
                        "reader",
                        "text: CPU s",
                        "text: speed-up vs `bvh`",
                        "file: CPU s",
                        "file: speed-up",
                        "load average",
                    ),
                    rows,
                ),  # fmt: skip
                "",
                f"Values: max abs difference to the `bvh` package "
                f"{max(r['max_abs_diff'] for r in report['corpora'].values()):.1e} (mocapnet without unwrapping). The "
                "hierarchy cache keeps the parse of the last 16 distinct HIERARCHY sections by content; the no-cache "
                "row clears it before every file.",
                "",
                "Synthetic hierarchies (CPU s): parse of a 10,000-joint tree (End Site on each of its 5,010 leaves, "
                f"defaults) {h['parse_10k_joint_tree_mocapnet_s']:.3f}"
                + (f" (reader at {baseline}: {h['parse_10k_joint_tree_baseline_s']:.3f})" if baseline else "")
                + f"; write + read of a 1,000-level chain {h['write_read_1000_level_chain_s']:.3f}.",
            ]
        )
        + "\n"
    )
