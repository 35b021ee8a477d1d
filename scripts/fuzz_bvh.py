"""Mutation fuzzing of the BVH reader (issue 14's acceptance run): 600 seeded cases, each one of 12 mutations
(truncation, line edits, bad numbers, braces, headers, stray bytes, damaged gzip, …) of one of 12 real files;
``read_bvh`` must round-trip it or raise ``MocapFileError`` naming the file in 5 s (``tests/io/test_bvh_fuzz.py``).
``python scripts/fuzz_bvh.py [--cases 60]`` writes benchmarks/results/bvh_io_fuzz.json and .md."""

from __future__ import annotations

import argparse
import collections
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the fuzzing engine lives in the test suite

from mocapnet.corpus import data_root  # noqa: E402
from mocapnet.evaluate.benchmark import git_commit  # noqa: E402
from mocapnet.evaluate.results import markdown_table, rounded, write_results  # noqa: E402
from mocapnet.threads import pin_threads  # noqa: E402
from tests.io.test_bvh_fuzz import fuzz_sources, run_mutations  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=600)
    parser.add_argument("--files", type=int, default=12, help="real files to mutate (default 12)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bvh_io_fuzz")
    args = parser.parse_args()
    pin_threads()
    sources = fuzz_sources(data_root() if data_root().exists() else None, args.files, None, args.seed)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        results = run_mutations(Path(folder), sources, args.cases, args.seed)  # raises on the first failure
    counts = collections.Counter((r["kind"], r["outcome"]) for r in results)
    by_kind = {k: {o: counts[(k, o)] for o in ("round-trip", "error")} for k in sorted({k for k, _ in counts})}
    s = {"cases": len(results), "failures": 0, "sources": [n for n, _ in sources],
         "source_bytes": sum(len(t) for _, t in sources), "max_case_seconds": max(r["seconds"] for r in results),
         "wall_seconds": time.perf_counter() - start, "by_kind": by_kind,
         "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}  # fmt: skip
    meta = {"command": "python " + " ".join(sys.argv), "commit": git_commit(short=True)}
    lines = [
        "# BVH reader: seeded mutation fuzzing",
        "",
        f"Command: `{meta['command']}` at commit {meta['commit']}. {s['cases']} cases on {len(sources)} real files "
        f"({s['source_bytes'] / 1e6:.1f} MB of text): every case round-tripped or raised `MocapFileError` naming "
        f"the file (and the line, for text damage); none failed.\nSlowest case {s['max_case_seconds']:.3g} s (limit "
        f"5 s); peak RSS of the whole run {s['peak_rss_mib']:.0f} MiB; wall time {s['wall_seconds']:.1f} s.",
        "",
        *markdown_table(["mutation", "round-trip", "error"], ([k, *v.values()] for k, v in s["by_kind"].items())),
    ]
    write_results(args.out, {"meta": meta, "summary": rounded(s, 3)}, "\n".join(lines) + "\n", indent=1)


if __name__ == "__main__":
    main()
