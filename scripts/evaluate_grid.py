"""Hydra entry point: evaluate a grid of corpora × corruptions × methods and write a markdown report.

    python scripts/evaluate_grid.py                         # mocapnet/conf/grid/sample.yaml
    python scripts/evaluate_grid.py grid=bandai2_noise fold=0
    python scripts/evaluate_grid.py corpora=[sample] corruptions=[gaps] methods=[lerp,spline] repeats=2
    python scripts/evaluate_grid.py grid=bandai2_gaps workers=0          # in this process, no Dask

For each (corpus, corruption) the report holds the summary table (ratios as in PROTOCOL.md) and a plot of
the error per motion (like the EBF paper's Figures 5 and 9); it also writes every row to rows.csv.gz.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

ROOT = Path(__file__).resolve().parents[1]


@hydra.main(version_base="1.3", config_path="../mocapnet/conf", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    from mocapnet.corpus import load_corpus
    from mocapnet.evaluate.benchmark import git_commit
    from mocapnet.evaluate.harness import evaluate, is_c3d_data
    from mocapnet.evaluate.report import evaluation_section, table, write_csv
    from mocapnet.parallel import Parallel
    from mocapnet.threads import pin_threads

    pin_threads(cfg.get("threads"))
    grid = cfg.get("grid", cfg)
    parallel = Parallel(cfg.get("scheduler"), cfg.get("workers"), cfg.get("threads", 1))
    out = ROOT / cfg.out_dir  # an absolute out_dir stays as it is
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# mocapnet evaluation grid", "",
             f"Command: `python scripts/evaluate_grid.py {' '.join(sys.argv[1:])}` at commit {git_commit(short=True)}.",
             f"Repeats: {cfg.repeats}; fold: {cfg.fold if cfg.fold is not None else 'all clips'}; limit: "
             f"{cfg.limit or 'none'}. Table entries are means over clips and repeats of each clip's error.",
             "", "```yaml", OmegaConf.to_yaml(cfg).strip(), "```"]  # fmt: skip
    rows = []
    for corpus_name in cfg.get("corpora") or grid.corpora:
        corpus = None if is_c3d_data(corpus_name) else load_corpus(corpus_name, limit=cfg.limit)
        for corruption in cfg.get("corruptions") or grid.corruptions:
            ev = evaluate(corpus_name, corruption, list(cfg.get("methods") or grid.methods), cfg.repeats, cfg.fold,
                          cfg.limit, corpus=corpus, parallel=parallel)  # fmt: skip
            rows += ev.rows
            lines += evaluation_section(ev, out / f"{ev.data}_{corruption.replace(':', '-')}.png")
            print(f"{ev.data}: {corruption}\n{table(ev)}\n", flush=True)
    write_csv(out / "rows.csv.gz", rows)
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'report.md'}")


if __name__ == "__main__":
    main()
