"""Offline cleaning speed of this checkout against an earlier commit, interleaved on the same machine: the
baseline is checked out in a temporary git worktree, and fresh processes of the two trees take turns, each
timing ``gaussian-58ms`` and a method (default ``ebf``) on one long bandai2 clip, 1 thread (median of its
cleans, wall and CPU time). The host's speed drifts from minute to minute, so only runs taken in turn compare.
``--profile`` adds where this checkout's time goes (cProfile of the method's cleans, top functions by own time).

    python scripts/bench_offline_ab.py --baseline f7c8869 --rounds 5 --out benchmarks/results/offline_ab_s22
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mocapnet.corpus import data_root
from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import fmt, markdown_table, provenance, provenance_header, write_results

#: What each child process runs (the code under test is the ``mocapnet`` its PYTHONPATH gives).
CHILD = """
import json, sys, time
import numpy as np
from mocapnet.corrupt import corrupt_motion
from mocapnet.evaluate.neural_bench import long_clip
from mocapnet.methods.registry import build_method
from mocapnet.threads import pin_threads
pin_threads(1)
method, frames, cleans, profile = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
clip = long_clip(frames)
noisy, mask = corrupt_motion(clip, "angular-0.5", np.random.default_rng(0))
out = {}
for text in ("gaussian-58ms", method):
    clean = build_method(text).clean
    clean(clip.with_channels(noisy), mask)
    wall, cpu = [], []
    for _ in range(cleans):
        t0, c0 = time.perf_counter(), time.process_time()
        clean(clip.with_channels(noisy), mask)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    out[text] = {"wall_fps": frames / float(np.median(wall)), "cpu_fps": frames / float(np.median(cpu))}
if profile:
    import cProfile, pstats
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(cleans):
        clean(clip.with_channels(noisy), mask)
    prof.disable()
    stats = pstats.Stats(prof)
    total = sum(v[2] for v in stats.stats.values())  # v: (calls, primitive calls, own time, cumulative time)
    top = sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:8]
    name = lambda k: k[2] if k[0] == "~" else f"{k[2]} ({k[0].rsplit('/', 1)[-1]}:{k[1]})"
    out["profile"] = [[name(k), v[2] / total] for k, v in top]
print("RESULT " + json.dumps(out))
"""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="git revision to compare against, e.g. f7c8869")
    parser.add_argument("--method", default="ebf", help="method string timed beside gaussian-58ms")
    parser.add_argument("--frames", type=int, default=10_000, help="clip length (bandai2 fold-0 clips joined)")
    parser.add_argument("--rounds", type=int, default=5, help="turns of (baseline, this checkout)")
    parser.add_argument("--cleans", type=int, default=5, help="timed cleans per process (median)")
    parser.add_argument("--profile", action="store_true", help="also profile this checkout's method")
    parser.add_argument("--out", default=os.path.join("benchmarks", "results", "offline_ab"))
    return parser.parse_args(argv)


def run_child(tree: Path, args: argparse.Namespace, profile: bool) -> dict:
    """One fresh process timing ``args.method`` with the ``mocapnet`` of ``tree``."""
    threads = {k: "1" for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    env = dict(os.environ, PYTHONPATH=str(tree), MOCAPNET_DATA=str(data_root().resolve()), **threads)
    argv = [sys.executable, "-c", CHILD, args.method, str(args.frames), str(args.cleans), "1" if profile else "0"]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir(), check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode or not lines:
        raise RuntimeError(f"timing process for {tree} failed ({done.returncode}): {done.stderr.strip()[-800:]}")
    return json.loads(lines[-1][len("RESULT ") :])


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    runs: dict[str, list[dict]] = {"baseline": [], "this": []}
    with tempfile.TemporaryDirectory(prefix="mocapnet_ab_") as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(base), args.baseline], check=True,
                       capture_output=True)  # fmt: skip
        try:
            for i in range(args.rounds):
                runs["baseline"].append(run_child(base, args, False))
                runs["this"].append(run_child(REPO, args, args.profile and i == args.rounds - 1))
                print(f"round {i + 1}: " + ", ".join(
                    f"{k} {r[-1][args.method]['wall_fps']:,.0f}" for k, r in runs.items()), flush=True)  # fmt: skip
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(base)], check=False)

    def median(tree: str, method: str, key: str) -> float:
        return float(np.median([r[method][key] for r in runs[tree]]))

    result = {**provenance(argv), "load": load, "baseline": args.baseline, "method": args.method,
              "frames": args.frames, "rounds": args.rounds, "runs": runs}  # fmt: skip
    rows = [
        [tree, method, fmt(median(tree, method, "wall_fps"), 0), fmt(median(tree, method, "cpu_fps"), 0)]
        for tree in runs
        for method in ("gaussian-58ms", args.method)
    ]
    text = provenance_header(f"Offline speed: this checkout vs {args.baseline}, interleaved", result)
    text += [
        f"{args.rounds} rounds of (baseline, this checkout), each a fresh process cleaning a {args.frames:,}-frame "
        f"bandai2 clip (angular-0.5) {args.cleans} times per method, 1 thread; medians over the rounds of each "
        "process's median, frames/s:",
        "",
        *markdown_table(["tree", "method", "wall frames/s", "CPU frames/s"], rows),
        "",
        f"{args.method} this ÷ baseline (wall): "
        f"{median('this', args.method, 'wall_fps') / median('baseline', args.method, 'wall_fps'):.2f}",
    ]
    profile = next((r["profile"] for r in runs["this"] if "profile" in r), None)
    if profile:
        text += ["", f"Where {args.method}'s time goes in this checkout (cProfile, own time):", ""]
        text += markdown_table(["function", "share"], [[name, f"{share:.0%}"] for name, share in profile])
    write_results(args.out, result, "\n".join(text) + "\n", indent=1)


if __name__ == "__main__":
    main()
