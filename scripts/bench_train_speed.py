"""Training speed on this machine's accelerator (``mocapnet.evaluate.train_speed``): a smoke run of every network,
then steps/s of the shipped EBF's architecture on the CPU (1 thread) and on the GPU at batch 32 and 256 (1 and 8
torch threads, or 4 and 8 DataLoader workers drawing the crops); ``--cpu``: the CPU alone, 1 thread, without and
with one worker process.

    python scripts/bench_train_speed.py --out benchmarks/results/train_speed     # needs a CUDA GPU
    python scripts/bench_train_speed.py --cpu      # writes benchmarks/results/train_speed_cpu.*
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import torch

from mocapnet.evaluate.results import provenance, write_results
from mocapnet.evaluate.train_speed import CPU_RUNS, markdown, smoke, step_rates


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--out", help="path without suffix (default benchmarks/results/train_speed, --cpu: train_speed_cpu)"
    )
    parser.add_argument("--runs-root", default="runs/train_speed", help="where the smoke runs write")
    parser.add_argument("--commit", help="the commit measured, when this checkout has no git history (a copy)")
    parser.add_argument("--cpu", action="store_true", help="CPU only: 1 thread without and with one loader worker")
    args = parser.parse_args(argv)
    out = args.out or os.path.join("benchmarks", "results", "train_speed_cpu" if args.cpu else "train_speed")
    if not args.cpu and not torch.cuda.is_available():
        parser.error("no CUDA GPU here: this benchmark compares the CPU with a GPU (--cpu: the CPU alone)")
    result = {**provenance(argv), "load": ", ".join(f"{x:.1f}" for x in os.getloadavg())}
    if args.commit:
        result["git_commit"] = args.commit
    if args.cpu:
        result["device"] = f"CPU ({os.cpu_count()} cores)"
        result["rates"] = step_rates(CPU_RUNS)
    else:
        result["device"] = torch.cuda.get_device_name(0)
        result["smoke"] = smoke(Path(args.runs_root), "gpu")
        result["rates"] = step_rates()
    write_results(out, result, markdown(result), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
