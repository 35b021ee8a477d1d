"""Train a cleaning network from the Hydra configs in ``mocapnet/conf/`` (same as ``mocapnet train``).

    python scripts/train.py experiment=bandai2_ebf                 # train (resumes if the run exists)
    python scripts/train.py experiment=bandai2_ebf ckpt_path=null  # start afresh
    python scripts/train.py experiment=sample_quick                # a few minutes on the shipped clip
    python scripts/train.py experiment=bandai2_ebf trainer.accelerator=gpu trainer.devices=2 trainer.strategy=ddp

Runs go to ``$MOCAPNET_RUNS/<name>`` (default ``runs/<name>``). Prints the best checkpoint's path.
On a shared CPU machine: ``nice -n 10`` and ``threads=1`` or ``2``. jemalloc can be preloaded
(``apt-get install -y libjemalloc2``, then ``LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libjemalloc.so.2``).
"""

from __future__ import annotations

import sys

from mocapnet.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
