"""Mutation fuzzing of the BVH reader: 600 seeded mutations of real files (issue 14's acceptance run).

Each case mutates a whole real file (a seeded sample of the shared corpora, else the shipped CMU clip) in one of
12 ways — truncation, deleted / duplicated / swapped lines, garbage and non-finite numbers, wrong channel
counts, broken braces, duplicate names, bad headers, stray bytes, damaged gzip — writes it (30 % gzipped), reads
it with ``read_bvh``, and requires a round trip or a ``MocapFileError`` naming the file (and the line for text
damage) within 5 s. The engine is the one the test suite runs (``tests/io/test_bvh_fuzz.py``, 120 cases).

    python scripts/fuzz_bvh.py                 # 600 cases on 12 whole files
    python scripts/fuzz_bvh.py --cases 60      # smoke run
Writes benchmarks/results/bvh_io_fuzz.json and .md.
"""

from __future__ import annotations

import argparse
import collections
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapnet.corpus import data_root  # noqa: E402
from mocapnet.evaluate.benchmark import git_commit  # noqa: E402
from tests.io.test_bvh_fuzz import fuzz_sources, run_mutations  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=600)
    parser.add_argument("--files", type=int, default=12, help="real files to mutate (default 12)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bvh_io_fuzz")
    args = parser.parse_args()
    root = data_root()
    sources = fuzz_sources(root if root.exists() else None, args.files, None, args.seed)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        results = run_mutations(Path(folder), sources, args.cases, args.seed)  # raises on the first failure
    wall = time.perf_counter() - start
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    by_kind = collections.Counter((r["kind"], r["outcome"]) for r in results)
    kinds = sorted({r["kind"] for r in results})
    summary = {
        "cases": len(results),
        "failures": 0,
        "sources": [name for name, _ in sources],
        "source_bytes": sum(len(text) for _, text in sources),
        "max_case_seconds": round(max(r["seconds"] for r in results), 3),
        "wall_seconds": round(wall, 1),
        "peak_rss_mib": round(peak_mib),
        "by_kind": {k: {o: by_kind[(k, o)] for o in ("round-trip", "error")} for k in kinds},
    }
    meta = {"command": "python " + " ".join(sys.argv), "commit": git_commit(short=True)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "summary": summary}, indent=1) + "\n")
    lines = [
        "# BVH reader: seeded mutation fuzzing",
        "",
        f"Command: `{meta['command']}` at commit {meta['commit']}. {summary['cases']} cases on "
        f"{len(sources)} real files ({summary['source_bytes'] / 1e6:.1f} MB of text): every case round-tripped "
        "or raised `MocapFileError` naming the file (and the line, for text damage); none failed.",
        f"Slowest case {summary['max_case_seconds']} s (limit 5 s); peak RSS of the whole run "
        f"{summary['peak_rss_mib']} MiB; wall time {summary['wall_seconds']} s.",
        "",
        "| mutation | round-trip | error |",
        "|---|---|---|",
    ]
    lines += [f"| {k} | {v['round-trip']} | {v['error']} |" for k, v in summary["by_kind"].items()]
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
