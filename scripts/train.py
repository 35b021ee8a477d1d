"""Train a cleaning network from the Hydra configs in ``conf/``.

    python scripts/train.py experiment=bandai2_ebf                 # train (resumes if the run exists)
    python scripts/train.py experiment=bandai2_ebf ckpt_path=null  # start afresh
    python scripts/train.py experiment=sample_quick                # a few minutes on the shipped clip
    python scripts/train.py experiment=bandai2_ebf trainer.accelerator=gpu trainer.devices=2 trainer.strategy=ddp

Runs go to ``$MOCAPNET_RUNS/<name>`` (default ``runs/<name>``). Prints the best checkpoint's path.
On a shared CPU machine: ``nice -n 10`` and ``threads=1`` or ``2``. jemalloc can be preloaded
(``apt-get install -y libjemalloc2``, then ``LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libjemalloc.so.2``); it is
optional and its measured effect on training speed is in ``benchmarks/results/neural.md``.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from mocapnet.nn.train import train


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
def main(cfg: DictConfig) -> None:
    print(train(cfg))


if __name__ == "__main__":
    main()
