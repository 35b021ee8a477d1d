"""Training speed of the networks on the machine at hand (``scripts/bench_train_speed.py``): a smoke run of
every network on the accelerator (one short epoch on the shipped sample, checkpoints written), then training
steps per second of the shipped bandai2 EBF's architecture (96 LSTM units, free-shape kernel, per-clip
normalisation, dropout 0.2, crops of 64-128 frames, every noise type) on the CPU with 1 thread and on the GPU
at batch 32 and 256 (and 256 with 8 torch threads, or with 4 or 8 DataLoader workers drawing the crops), in one
process, so the ratios compare like with like; ``CPU_RUNS`` (no GPU needed): the CPU with and without one worker.
The first steps (warm-up, CUDA kernels' first launch) are not timed."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch

from mocapnet.evaluate.results import fmt, markdown_table, provenance_header
from mocapnet.nn.train import build, compose_config, configure_torch, train

QUICK = ("data=sample", "~logger", "trainer.enable_progress_bar=false", "trainer.max_time=null")
SHIPPED_EBF = (
    "model=ebf",
    "model.hidden=96",
    "model.filter_shape=free",
    "model.bias=false",
    "model.norm=clip",
    "model.dropout=0.2",
    "data.crop_min=64",
    "data.crop_max=128",
    "corruption=mix",
)
#: (label, accelerator, batch size, torch threads, DataLoader workers) of the timed runs: the CPU alone, and
#: the CPU against the GPU (whose large batches the one-process crop pipeline cannot feed: workers).
CPU_RUNS = (("cpu", "cpu", 32, 1, 0), ("cpu", "cpu", 32, 1, 1))
RATE_RUNS = (
    ("cpu", "cpu", 32, 1, 0),
    ("gpu", "gpu", 32, 1, 0),
    ("gpu", "gpu", 256, 1, 0),
    ("gpu", "gpu", 256, 8, 0),
    ("gpu", "gpu", 256, 1, 4),
    ("gpu", "gpu", 256, 1, 8),
)


class StepClock(L.Callback):
    """Steps per second after the first ``skip`` steps (CUDA synchronised at both ends)."""

    def __init__(self, skip: int = 5) -> None:
        self.skip, self.start, self.rate = skip, 0.0, float("nan")

    @staticmethod
    def _now() -> float:
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        return time.perf_counter()

    def on_train_batch_start(self, trainer: L.Trainer, *args: Any) -> None:
        if trainer.global_step == self.skip:
            self.start = self._now()

    def on_train_end(self, trainer: L.Trainer, *args: Any) -> None:
        if trainer.global_step <= self.skip:
            raise ValueError(f"timed {trainer.global_step} steps: more than the {self.skip} untimed ones are needed")
        self.rate = (trainer.global_step - self.skip) / (self._now() - self.start)


def smoke(runs_root: Path, accelerator: str) -> list[dict[str, Any]]:
    """Each network (EBF, EBD, NN, BF) trained one 10-step epoch with validation and checkpoints on
    ``accelerator``: ``{"model", "seconds", "checkpoint"}`` rows (an exception fails the benchmark)."""
    rows = []
    for model, extra in (("ebf", []), ("ebd", ["corruption=gaps"]), ("nn", []), ("bf", [])):
        overrides = [*QUICK, f"model={model}", f"trainer.accelerator={accelerator}", "trainer.devices=1", *extra]
        overrides += ["trainer.max_epochs=1", "data.steps_per_epoch=10", "threads=1", f"runs_root={runs_root}"]
        start = time.perf_counter()
        best = train(compose_config([*overrides, f"name=smoke_{model}"]))
        rows.append({"model": model, "seconds": time.perf_counter() - start, "checkpoint": best.name})
    return rows


def step_rates(runs: Sequence[tuple[str, str, int, int, int]] = RATE_RUNS, steps: int = 45) -> list[dict[str, Any]]:
    """Training steps per second of ``SHIPPED_EBF`` on the sample for each ``(label, accelerator, batch,
    threads, workers)``: ``{"label", "batch", "threads", "workers", "steps_per_s", "crops_per_s"}`` rows."""
    rows = []
    for label, accelerator, batch, threads, workers in runs:
        cfg = compose_config(
            [
                *QUICK,
                *SHIPPED_EBF,
                f"data.batch_size={batch}",
                "data.steps_per_epoch=1000",
                f"data.num_workers={workers}",
            ]
        )
        configure_torch(threads)
        data, net = build(cfg)
        clock = StepClock()
        trainer = L.Trainer(
            accelerator=accelerator,
            devices=1,
            max_steps=steps,
            logger=False,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            limit_val_batches=0,
            callbacks=[clock],
        )
        trainer.fit(net, datamodule=data)
        rows.append(
            {
                "label": label,
                "batch": batch,
                "threads": threads,
                "workers": workers,
                "steps_per_s": clock.rate,
                "crops_per_s": clock.rate * batch,
            }  # fmt: skip
        )
    return rows


def markdown(result: dict[str, Any]) -> str:
    lines = provenance_header("Training speed", result)
    lines += [f"Device: {result['device']}", ""]
    if result.get("smoke"):
        lines += ["Smoke run (one 10-step epoch, validation, checkpoints):", ""]
        lines += markdown_table(["network", "seconds", "best"], [[r["model"], fmt(r["seconds"], 1), r["checkpoint"]]
                                                              for r in result["smoke"]])  # fmt: skip
        lines.append("")
    cpu = next(r["crops_per_s"] for r in result["rates"] if r["label"] == "cpu" and not r.get("workers"))
    lines += ["Shipped bandai2 EBF architecture on the sample clip, steps per second:", ""]
    lines += markdown_table(
        ["device", "batch", "torch threads", "loader workers", "steps/s", "crops/s", "crops/s ÷ CPU's"],
        [
            [
                r["label"],
                r["batch"],
                r["threads"],
                r.get("workers", 0),
                fmt(r["steps_per_s"], 2),
                fmt(r["crops_per_s"], 0),
                fmt(r["crops_per_s"] / cpu, 1),
            ]  # fmt: skip
            for r in result["rates"]
        ],
    )
    return "\n".join(lines) + "\n"
