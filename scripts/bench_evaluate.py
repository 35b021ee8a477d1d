"""Benchmark: CPU and wall time of ``mocapnet evaluate`` before and after the parallel, vectorised harness.

Three runs of the same command line as child processes, each one's CPU time = user + system of the process
and every worker it started (the work is in ``mocapnet.evaluate.speed_bench``):

* ``before``: the harness at ``--old`` (default 58b4b19), in one process, as it was;
* ``after, 1 process``: the harness at ``--new`` (default HEAD) with ``--workers 0``;
* ``after, Dask``: the same on a local Dask cluster of ``--workers`` processes (default: one per core).

``--rounds N`` repeats the three in rotating order (interleaved). Since the one reference rule, ``after`` adds
``gaussian-tuned`` (a reference for noise), so ``before`` is given ``--method gaussian-tuned`` too: both tune
and score the same four methods. The rows of the other methods must agree to 1e-9, per metric.

    nice -n 5 .venv/bin/python scripts/bench_evaluate.py        # 1,000 bandai2 clips, gaussian-58ms, 5 repeats
    .venv/bin/python scripts/bench_evaluate.py --limit 50 --repeats 1 --out /tmp/speed   # smoke run
Writes benchmarks/results/evaluate_speed.md and .json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mocapnet.corpus import data_root, load_corpus
from mocapnet.evaluate import speed_bench
from mocapnet.evaluate.benchmark import REPO
from mocapnet.evaluate.results import provenance, write_results
from mocapnet.parallel import local_cores
from mocapnet.threads import pin_threads


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default="bandai2", help="corpus (default bandai2)")
    parser.add_argument("--limit", type=int, default=1000, help="clips (default 1000)")
    parser.add_argument("--repeats", type=int, default=5, help="corrupted copies per clip (default 5)")
    parser.add_argument("--method", default="gaussian-58ms")
    parser.add_argument("--corruption", default="angular-0.5")
    parser.add_argument("--old", default="58b4b19", help="commit of the harness before (default 58b4b19)")
    parser.add_argument("--new", default="HEAD", help="commit of the harness after (default HEAD)")
    parser.add_argument("--workers", type=int, default=local_cores(), help="Dask workers (default: one per core)")
    parser.add_argument("--rounds", type=int, default=1, help="interleaved rounds of the three runs (default 1)")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results", help="output folder")
    args = parser.parse_args(argv)
    pin_threads(1)
    report = provenance(argv)
    load_corpus(args.data, progress=False, limit=args.limit)  # the parse cache is warm for every run
    common = ["evaluate", "--data", args.data, "--limit", str(args.limit), "--repeats", str(args.repeats)]
    common += ["--corruption", args.corruption, "--method", args.method, "--quiet"]
    report.update(mocapnet_args=common, cores=local_cores())
    report.update(speed_bench.measure(common, args.old, args.new, data_root(), args.rounds, args.workers))
    title = f"`mocapnet evaluate` speed: {args.limit} {args.data} clips × {args.repeats} repeats, {args.method}"
    write_results(args.out / "evaluate_speed", report, speed_bench.markdown(report, title), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
