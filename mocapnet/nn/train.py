"""Training from a composed Hydra config (``mocapnet/conf/train.yaml``), in this process:
``mocapnet train OVERRIDES…`` calls ``main(overrides)`` (``scripts/train.py`` is a thin wrapper of it).

``compose_config(overrides)`` composes the packaged configs with Hydra's compose API (so an installed package
trains from any directory, and a killed ``mocapnet train`` leaves no child process behind).

``train(cfg)`` builds the data module and the model from ``cfg.data`` / ``cfg.model`` (Hydra ``_target_``),
copies the training-set normaliser into the model, and fits with a Lightning ``Trainer`` from
``cfg.trainer``, TensorBoard logging from ``cfg.logger`` and two checkpoints under ``<run_dir>/checkpoints``:
``best.ckpt`` (lowest validation error; model selection uses validation only) and ``last.ckpt``
(``ckpt_path=last`` resumes a killed run from it, optimizer, scheduler, data stream and time budget included).
``init_from=PATH`` starts a new run from another run's weights (a warm restart: fresh optimizer, schedule and
budget; the model's hyper-parameters must be the checkpoint's); a run that resumes from ``last.ckpt`` ignores it.
With ``ema_decay`` set, an exponential moving average of the weights (Lightning's ``EMAWeightAveraging``) is
what validation scores and what both checkpoints hold as ``state_dict``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import hydra
import lightning as L
import torch
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from hydra.errors import HydraException
from lightning.pytorch.callbacks import EMAWeightAveraging, LearningRateMonitor, ModelCheckpoint
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from mocapnet.io.atomic import MocapFileError
from mocapnet.nn.base import CleanerModule
from mocapnet.nn.checkpoints import read_checkpoint
from mocapnet.nn.data import MotionDataModule
from mocapnet.threads import pin_threads

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def compose_config(overrides: Sequence[str]) -> DictConfig:
    """``train.yaml`` composed with Hydra ``overrides`` (e.g. ``experiment=sample_quick``), Hydra's runtime
    config set so ``${hydra:runtime.choices.*}`` resolves; ValueError naming the problem for an unknown
    group, option or key, or an override that does not parse."""
    experiments = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
    for item in overrides:
        key, _, value = item.partition("=")
        if key.lstrip("+~") == "experiment" and value not in experiments:
            raise ValueError(f"training config: no experiment {value!r}; the experiments are {', '.join(experiments)}")
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3", job_name="train"):
            cfg = compose("train", overrides=list(overrides), return_hydra_config=True)
    except (HydraException, OmegaConfBaseException) as exc:
        raise ValueError(f"training config: {' '.join(str(exc).split())[:300]}") from None
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg.hydra
    return cfg


def main(overrides: Sequence[str]) -> Path:
    """Compose the configs with ``overrides`` and train; return the best checkpoint's path."""
    return train(compose_config(overrides))


def configure_torch(threads: int | None) -> None:
    """CPU settings for training and inference: thread count and flush-to-zero for denormals (tanh/LSTM
    gradients otherwise slow the CPU down by hitting denormal arithmetic). ``threads`` pins torch and BLAS
    together through ``mocapnet.threads.pin_threads``; None leaves the libraries' defaults."""
    if threads:
        pin_threads(int(threads))
    torch.set_flush_denormal(True)


def resume_path(ckpt_path: str | None, ckpt_dir: Path, averaged: bool = False) -> str | None:
    """The checkpoint a run resumes from: ``"last"`` → ``ckpt_dir/last.ckpt`` when it exists (else a fresh
    start), a path → that file, None → a fresh start. The file is read once as data first
    (``checkpoints.read_checkpoint``: FileNotFoundError, or MocapFileError naming it when it is truncated,
    foreign or would need code to load); Lightning then loads it with ``weights_only=True`` too. ``averaged``:
    the run keeps a weight average (``ema_decay``); a checkpoint written with the other setting is refused
    (MocapFileError), since its ``state_dict`` would be taken for the wrong weights."""
    if ckpt_path is None:
        return None
    path = ckpt_dir / "last.ckpt" if ckpt_path == "last" else Path(ckpt_path)
    if ckpt_path == "last" and not path.exists():
        return None
    ckpt = read_checkpoint(path)
    if "loops" not in ckpt or "state_dict" not in ckpt:
        raise MocapFileError(f"{path}: not a training checkpoint to resume from (no loop state); start afresh")
    if ("current_model_state" in ckpt) != averaged:
        was = "with" if "current_model_state" in ckpt else "without"
        raise MocapFileError(f"{path}: written {was} ema_decay; resume with the same setting or start afresh")
    return str(path)


#: Hyper-parameters a warm restart may change: how to train (the loss too: ``gap_loss``, ``loss``) or start
#: (``sigma_init``, overwritten by the loaded weights), and the inference-only settings a shipped checkpoint carries
#: (``change_limit``, ``gap_blend``).
_RETUNABLE = frozenset(
    {
        "lr",
        "weight_decay",
        "lr_patience",
        "lr_schedule",
        "dropout",
        "gap_loss",
        "loss",
        "sigma_init",
        "change_limit",
        "gap_blend",
    }
)


def initial_weights(model: CleanerModule, ckpt: dict, path: str | Path) -> None:
    """Load the weights (normaliser included) of checkpoint ``ckpt`` (read as data from ``path`` by
    ``checkpoints.read_checkpoint``) into ``model``. MocapFileError naming the file when it holds no weights, was
    trained for another network class or skeleton, or its tensors do not fit ``model`` (other sizes or layers)."""
    state = ckpt.get("state_dict")
    if not isinstance(state, dict):
        raise MocapFileError(f"{path}: holds no state_dict to start from")
    kind, wanted = ckpt.get("mocapnet_model"), type(model).__name__
    if kind is not None and kind != wanted:
        raise MocapFileError(f"{path}: holds {kind} weights, this run trains {wanted}")
    theirs = ckpt.get("hyper_parameters") or {}
    if theirs.get("skeleton_hash") is not None and theirs["skeleton_hash"] != model.hparams.get("skeleton_hash"):
        raise MocapFileError(
            f"{path}: trained on another skeleton ({theirs['skeleton_hash']}, this run's data: "
            f"{model.hparams.get('skeleton_hash')})"
        )
    for key, value in model.hparams.items():  # what the weights mean (inputs, normalisation), not how to train
        if key not in _RETUNABLE and key in theirs and theirs[key] != value:
            raise MocapFileError(f"{path}: trained with {key}={theirs[key]!r}, this run has {key}={value!r}")
    try:
        model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})
    except RuntimeError as exc:
        reason = " ".join(str(exc).split())[:300]
        raise MocapFileError(f"{path}: its weights do not fit this run's model ({reason})") from None


def build(cfg: DictConfig) -> tuple[MotionDataModule, CleanerModule]:
    """Data module (set up) and a fresh model sized for it, with its normaliser set. The interpolation the data
    puts into gaps (``data.spline_max_s``) must be the one the model corrects (an EBD's ``spline_max_s``; other
    networks are run on linear interpolation), else ValueError."""
    data_spline = float(cfg.data.get("spline_max_s", 0.0))
    model_spline = float(cfg.model.get("spline_max_s", 0.0))
    if data_spline != model_spline:
        raise ValueError(
            f"data.spline_max_s={data_spline:g} but model.spline_max_s={model_spline:g}: a network must be trained on "
            "the interpolation it is run on (set both, e.g. model.spline_max_s=${data.spline_max_s}, on an EBD)"
        )
    data: MotionDataModule = hydra.utils.instantiate(cfg.data, seed=cfg.seed, _convert_="all")
    data.setup("fit")
    model: CleanerModule = hydra.utils.instantiate(
        cfg.model,
        n_channels=data.n_channels,
        skeleton_hash=data.skeleton_hash,
        fps=data.fps,
        corpus=cfg.data.corpus,
        _convert_="all",
    )
    model.set_normaliser(data.normaliser())
    return data, model


def weight_averaging(ema_decay: float | None) -> list[EMAWeightAveraging]:
    """The weight-averaging callback for ``ema_decay`` (none for ``None``), else ValueError."""
    if ema_decay is None:
        return []
    if isinstance(ema_decay, bool) or not isinstance(ema_decay, (int, float)) or not 0.0 < ema_decay < 1.0:
        raise ValueError(f"training config: ema_decay must be a number in (0, 1) or null, got {ema_decay!r}")
    # the buffers (the normaliser) are fixed before training: averaging them would only add rounding drift
    return [EMAWeightAveraging(decay=float(ema_decay), use_buffers=False)]


def train(cfg: DictConfig) -> Path:
    """Fit the configured model; return the path of the best checkpoint (or the last one when validation
    never ran). Writes ``<run_dir>/config.yaml`` and ``<run_dir>/result.json`` (best score, paths)."""
    averaging = weight_averaging(cfg.get("ema_decay"))
    run_dir = Path(cfg.run_dir)
    ckpt_dir = run_dir / "checkpoints"
    ckpt_path = resume_path(cfg.get("ckpt_path"), ckpt_dir, averaged=bool(averaging))
    # a missing or unreadable file fails now, before the data is set up; the weights are loaded after
    start = read_checkpoint(cfg.init_from) if ckpt_path is None and cfg.get("init_from") else None
    configure_torch(cfg.get("threads"))
    L.seed_everything(cfg.seed, workers=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    data, model = build(cfg)
    if start is not None:
        initial_weights(model, start, cfg.init_from)
    best = ModelCheckpoint(dirpath=ckpt_dir, filename="best", monitor=model.val_metric, mode="min", save_top_k=1)
    # Lightning >= 2.6 writes ``save_last`` only when the monitored score improves, so a run resumed after a
    # plateau would lose every epoch since its best: the latest state is a checkpoint of its own, every epoch
    latest = ModelCheckpoint(dirpath=ckpt_dir, filename="last", save_top_k=1, enable_version_counter=False)
    callbacks = [best, latest, LearningRateMonitor()] if cfg.get("logger") else [best, latest]
    callbacks += averaging
    logger = hydra.utils.instantiate(cfg.logger, save_dir=str(run_dir)) if cfg.get("logger") else False
    trainer = L.Trainer(**OmegaConf.to_container(cfg.trainer, resolve=True), callbacks=callbacks, logger=logger)
    trainer.fit(model, datamodule=data, ckpt_path=ckpt_path, weights_only=True)
    result = Path(best.best_model_path) if best.best_model_path else ckpt_dir / "last.ckpt"
    if trainer.is_global_zero:
        score = best.best_model_score
        summary = {
            "best": str(result),
            "last": str(ckpt_dir / "last.ckpt"),
            "monitor": model.val_metric,
            "best_score": None if score is None else float(score),
            "epochs": trainer.current_epoch,
            "global_step": trainer.global_step,
        }
        (run_dir / "result.json").write_text(json.dumps(summary, indent=1) + "\n")
    return result
