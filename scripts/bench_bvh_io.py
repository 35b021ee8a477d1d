"""Benchmark: BVH loading CPU time of mocapnet's reader vs the PyPI ``bvh`` package (the reference).

Per file, the readers run back to back in an order that rotates from file to file (interleaved), each timed
with ``time.process_time`` (CPU time of this process, so other jobs on a shared machine count less), over
several rounds. Two measurements:

* text: both parse the same decompressed text already in memory into a float array ``[T, C]`` plus the
  joint names; mocapnet runs with ``read_bvh``'s defaults (every check, unit guess, unwrapping);
* file: ``read_bvh(path)`` vs ``gzip`` + the ``bvh`` package on the same ``.bvh.gz`` file.

The text measurement also times mocapnet with its hierarchy cache cleared before every file, and (with
``--baseline COMMIT``) the reader of an older commit, so a speed-up on a busy machine has its reference.

Values are compared file by file (mocapnet without unwrapping vs the package). It also times the parse of a
synthetic 10,000-joint hierarchy and the write + read of a 1,000-level chain.

    python scripts/bench_bvh_io.py                      # first 830 files of bandai2 + all of bandai1
    python scripts/bench_bvh_io.py --files 100 --quick  # smoke run
    python scripts/bench_bvh_io.py --baseline 0313cc4   # also the reader of an older commit, same run
Writes benchmarks/results/bvh_io.json and .md.
"""

from __future__ import annotations

import argparse
import gzip
import json
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapnet.corpus import data_root, list_bvh  # noqa: E402
from mocapnet.evaluate.benchmark import git_commit  # noqa: E402
from mocapnet.io import bvh as bvh_module  # noqa: E402
from mocapnet.io.bvh import format_bvh, parse_bvh, read_bvh  # noqa: E402
from mocapnet.motion import Motion, Skeleton  # noqa: E402


def read_with_bvh_package(text: str) -> tuple[np.ndarray, list[str]]:
    from bvh import Bvh

    mocap = Bvh(text)
    return np.array(mocap.frames, dtype=np.float64), mocap.get_joints_names()


def interleaved(readers: dict[str, Callable], items: list, rounds: int) -> dict[str, float]:
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
        ["git", "show", f"{commit}:mocapnet/io/bvh.py"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout
    module = ModuleType(f"bvh_at_{commit}")
    exec(compile(source, f"bvh.py@{commit}", "exec"), module.__dict__)  # noqa: S102 - our own file from git
    return module


def parse_without_cache(item: tuple[str, Path]) -> None:
    bvh_module._HIERARCHY_CACHE.clear()
    parse_bvh(*item)


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


def hierarchy_timings(baseline: ModuleType | None) -> dict:
    """CPU seconds: parse a 10,000-joint tree with ``read_bvh``'s defaults (unit guess included; also with the
    baseline reader when given); write and read a 1,000-level chain."""
    text = format_bvh(synthetic(10_000, chain=False))
    timings = {}
    for name, parse in [("mocapnet", parse_bvh)] + ([("baseline", baseline.parse_bvh)] if baseline else []):
        bvh_module._HIERARCHY_CACHE.clear()
        t0 = time.process_time()
        m = parse(text, "tree10k.bvh")
        timings[f"parse_10k_joint_tree_{name}_s"] = round(time.process_time() - t0, 3)
        assert m.skeleton.n_joints == 10_000
    chain = synthetic(1_000, chain=True)
    t0 = time.process_time()
    back = parse_bvh(format_bvh(chain), "chain1000.bvh", cm_per_unit=1.0, unwrap=False)
    timings["write_read_1000_level_chain_s"] = round(time.process_time() - t0, 3)
    assert np.abs(back.channels - chain.channels).max() < 1e-6
    return timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=None, help="shared data root (default: MOCAPNET_DATA)")
    parser.add_argument("--files", type=int, default=830, help="bandai2 files to load (default 830)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default 3)")
    parser.add_argument("--quick", action="store_true", help="skip bandai1")
    parser.add_argument("--baseline", default=None, help="also time mocapnet/io/bvh.py of this git commit")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bvh_io")
    args = parser.parse_args()
    root = args.data_root or data_root()
    sets = {"bandai2": list_bvh(root / "bvh/bandai_namco_2")[: args.files]}
    if not args.quick:
        sets["bandai1"] = list_bvh(root / "bvh/bandai_namco_1")
    baseline = previous_reader(args.baseline) if args.baseline else None
    results = {}
    for name, files in sets.items():
        texts = [gzip.open(f, "rb").read().decode() for f in files]
        max_diff, frames = 0.0, 0
        for text, f in zip(texts, files):
            m = parse_bvh(text, f, unwrap=False)
            arr, names = read_with_bvh_package(text)
            assert list(m.skeleton.names) == names, f
            max_diff = max(max_diff, float(np.abs(m.channels - arr).max()))
            frames += m.n_frames
        items = list(zip(texts, files))
        text_readers = {
            "mocapnet": lambda it: parse_bvh(*it),
            "bvh package": lambda it: read_with_bvh_package(it[0]),
            "mocapnet, no hierarchy cache": parse_without_cache,
        }
        if baseline is not None:
            text_readers[f"mocapnet at {args.baseline}"] = lambda it: baseline.parse_bvh(*it)
        text = interleaved(text_readers, items, args.rounds)
        file = interleaved(
            {"mocapnet": read_bvh, "bvh package": lambda f: read_with_bvh_package(gzip.open(f, "rb").read().decode())},
            files,
            args.rounds,
        )
        results[name] = {
            "files": len(files),
            "frames": frames,
            "rounds": args.rounds,
            "text_cpu_s": {k: round(v, 3) for k, v in text.items()},
            "text_speedup_vs_bvh_package": {k: round(text["bvh package"] / v, 1) for k, v in text.items()},
            "file_cpu_s": {k: round(v, 3) for k, v in file.items()},
            "file_speedup": round(file["bvh package"] / file["mocapnet"], 1),
            "max_abs_diff": max_diff,
        }
        print(name, results[name], flush=True)
    hierarchy = hierarchy_timings(baseline)
    print(hierarchy)
    meta = {
        "command": "python " + " ".join(sys.argv),
        "commit": git_commit(short=True),
        "machine": f"{platform.processor() or platform.machine()}, {platform.python_version()}",
        "numpy": np.__version__,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"meta": meta, "results": results, "hierarchy": hierarchy}
    args.out.with_suffix(".json").write_text(json.dumps(payload, indent=1) + "\n")
    lines = [
        "# BVH loading: mocapnet vs the PyPI `bvh` package (CPU time, interleaved)",
        "",
        f"Command: `{meta['command']}` at commit {meta['commit']} on {meta['machine']}, numpy {meta['numpy']}.",
        "CPU seconds (`time.process_time`) summed over all files and rounds; per file the readers run back to back",
        "in an order that rotates from file to file.",
        "text = both parse the same in-memory text (mocapnet with `read_bvh`'s defaults: checks, unit guess,",
        "unwrapping); file = `read_bvh(path)` vs gzip + the package on the same `.bvh.gz`.",
        "",
        "| corpus | files | frames | reader | text: CPU s | text: speed-up vs `bvh` | file: CPU s | file: speed-up |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        for reader, seconds in r["text_cpu_s"].items():
            file_s = r["file_cpu_s"].get(reader, "")
            speedup = r["text_speedup_vs_bvh_package"][reader]
            file_speedup = {"mocapnet": f"{r['file_speedup']}×", "bvh package": "1.0×"}.get(reader, "")
            lines.append(
                f"| {name} | {r['files']} | {r['frames']} | {reader} | {seconds} | {speedup}× | {file_s} | "
                f"{file_speedup} |"
            )
    lines += [
        "",
        f"Values: max abs difference to the `bvh` package {max(r['max_abs_diff'] for r in results.values()):.1e} "
        "(mocapnet without unwrapping). The hierarchy cache keeps the parse of the last 16 distinct HIERARCHY "
        "sections by content; the no-cache row clears it before every file.",
    ]
    lines += [
        "",
        "Synthetic hierarchies (CPU s): parse of a 10,000-joint tree (End Site on each of its 5,010 leaves, "
        f"defaults) {hierarchy['parse_10k_joint_tree_mocapnet_s']}"
        + (f" (reader at {args.baseline}: {hierarchy['parse_10k_joint_tree_baseline_s']})" if args.baseline else "")
        + f"; write + read of a 1,000-level chain {hierarchy['write_read_1000_level_chain_s']}.",
    ]
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
