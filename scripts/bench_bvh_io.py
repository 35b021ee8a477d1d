"""Benchmark: BVH loading time of mocapnet's reader vs the PyPI ``bvh`` package (the reference).

Both readers start from the same decompressed text already in memory (gzip excluded) and must deliver a
float array ``[T, C]`` of the frames plus the joint names; mocapnet also builds the skeleton, checks every
value and unwraps the Euler channels. Values are compared file by file (before unwrapping).

    python scripts/bench_bvh_io.py                      # first 830 files of bandai2 + all of bandai1
    python scripts/bench_bvh_io.py --files 100 --quick  # smoke run
Writes benchmarks/results/bvh_io.json and .md.
"""

from __future__ import annotations

import argparse
import gzip
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapnet.corpus import data_root, list_bvh  # noqa: E402
from mocapnet.evaluate.benchmark import git_commit  # noqa: E402
from mocapnet.io.bvh import parse_bvh  # noqa: E402


def read_with_bvh_package(text: str) -> tuple[np.ndarray, list[str]]:
    from bvh import Bvh

    mocap = Bvh(text)
    return np.array(mocap.frames, dtype=np.float64), mocap.get_joints_names()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, default=None, help="shared data root (default: MOCAPNET_DATA)")
    parser.add_argument("--files", type=int, default=830, help="bandai2 files to load (default 830)")
    parser.add_argument("--quick", action="store_true", help="skip bandai1")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bvh_io")
    args = parser.parse_args()
    root = args.data_root or data_root()
    sets = {"bandai2": list_bvh(root / "bvh/bandai_namco_2")[: args.files]}
    if not args.quick:
        sets["bandai1"] = list_bvh(root / "bvh/bandai_namco_1")
    results = {}
    for name, files in sets.items():
        texts = [gzip.open(f, "rb").read().decode() for f in files]
        frames = 0
        t0 = time.perf_counter()
        ours = [parse_bvh(text, f, unwrap=False) for text, f in zip(texts, files)]
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        theirs = [read_with_bvh_package(text) for text in tqdm(texts, desc=f"bvh package on {name}", unit="file")]
        t_theirs = time.perf_counter() - t0
        max_diff = 0.0
        for m, (arr, names) in zip(ours, theirs):
            assert list(m.skeleton.names) == names, m.name
            max_diff = max(max_diff, float(np.abs(m.channels - arr).max()))
            frames += m.n_frames
        results[name] = {
            "files": len(files),
            "frames": frames,
            "mocapnet_s": round(t_ours, 3),
            "bvh_package_s": round(t_theirs, 3),
            "speedup": round(t_theirs / t_ours, 1),
            "max_abs_diff": max_diff,
        }
        print(name, results[name])
    commit = git_commit(short=True)
    meta = {
        "command": "python " + " ".join(sys.argv),
        "commit": commit,
        "machine": f"{platform.processor() or platform.machine()}, {platform.python_version()}",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
    lines = [
        "# BVH loading: mocapnet vs the PyPI `bvh` package",
        "",
        f"Command: `{meta['command']}` at commit {meta['commit']} on {meta['machine']}.",
        "Both parse the same in-memory text (gzip excluded) into a float `[T, C]` array + joint names.",
        "",
        "| corpus | files | frames | mocapnet s | bvh package s | speed-up | max abs diff |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r['files']} | {r['frames']} | {r['mocapnet_s']} | {r['bvh_package_s']} | "
            f"{r['speedup']}× | {r['max_abs_diff']:.1e} |"
        )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
