"""Hydra configs, the training entry point, determinism and resuming."""

from __future__ import annotations

import json
import math
from pathlib import Path

import hydra
import lightning as L
import pytest
import torch
from omegaconf import OmegaConf

from mocapnet.io.atomic import MocapFileError
from mocapnet.nn import EBD, EBF, WindowMLP
from mocapnet.nn.checkpoints import read_checkpoint
from mocapnet.nn.data import MotionDataModule
from mocapnet.nn.train import CONF_DIR, compose_config, train

EXPERIMENTS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))
TINY_MODEL = {
    "ebf": ["model.hidden=8", "model.code=8", "model.width=16"],
    "bf": ["model.hidden=8", "model.width=16"],
    "ebd": ["model.hidden=8", "model.code=8", "model.width=16"],
    "nn": ["model.widths=[16,16,16,16,16]"],
}
QUICK = [
    "data=sample",
    "~logger",
    "threads=1",
    "trainer.enable_progress_bar=false",
    "trainer.max_time=null",
    "data.batch_size=4",
    "data.crop_min=32",
    "data.crop_max=48",
    "data.steps_per_epoch=2",
]


def compose_cfg(overrides: list[str]):
    """Compose ``mocapnet/conf/train.yaml`` as ``mocapnet train`` does."""
    return compose_config(overrides)


def test_every_experiment_exists():
    assert {"bandai2_ebf", "bandai2_ebd", "cmu120_ebf", "cmu120_ebd", "sample_quick"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_configs_instantiate(experiment, tmp_path):
    cfg = compose_cfg([f"experiment={experiment}", f"runs_root={tmp_path}"])
    data = hydra.utils.instantiate(cfg.data, seed=cfg.seed, _convert_="all")
    assert isinstance(data, MotionDataModule) and data.hparams.corruptions == list(cfg.corruption.train)
    model = hydra.utils.instantiate(cfg.model, n_channels=6, _convert_="all")
    assert isinstance(model, (EBF, EBD, WindowMLP))
    logger = hydra.utils.instantiate(cfg.logger, save_dir=str(tmp_path))
    trainer = L.Trainer(**OmegaConf.to_container(cfg.trainer, resolve=True), logger=logger)
    assert trainer.max_epochs == cfg.trainer.max_epochs
    assert cfg.run_dir == f"{tmp_path}/{cfg.name}"


def test_gpu_and_ddp_trainer_configs_compose():
    for group, devices in (("gpu", 1), ("ddp", 2)):
        cfg = compose_cfg([f"trainer={group}"])
        assert cfg.trainer.accelerator == "gpu" and cfg.trainer.devices == devices
    cfg = compose_cfg(["trainer.accelerator=gpu", "trainer.devices=2", "trainer.strategy=ddp"])
    assert cfg.trainer.strategy == "ddp"


@pytest.mark.parametrize("model", sorted(TINY_MODEL))
def test_fast_dev_run(model, tmp_path):
    corruption = "gaps" if model == "ebd" else "angular"
    cfg = compose_cfg(
        [f"model={model}", f"corruption={corruption}", f"runs_root={tmp_path}", "+trainer.fast_dev_run=true"]
        + QUICK
        + TINY_MODEL[model]
    )
    train(cfg)
    assert (tmp_path / cfg.name / "result.json").exists()


def test_fast_dev_run_with_the_gaussian_ratio_loss(tmp_path):
    cfg = compose_cfg(
        [
            "model=ebf",
            "corruption=angular",
            f"runs_root={tmp_path}",
            "+trainer.fast_dev_run=true",
            "model.loss=gaussian_ratio",
        ]
        + QUICK
        + TINY_MODEL["ebf"]
    )
    train(cfg)
    assert (tmp_path / cfg.name / "result.json").exists()


def _final_state(tmp_path: Path, name: str, epochs: int, ckpt_path: str = "null") -> dict[str, torch.Tensor]:
    cfg = compose_cfg(
        [f"runs_root={tmp_path}", f"name={name}", f"trainer.max_epochs={epochs}", f"ckpt_path={ckpt_path}"]
        + QUICK
        + TINY_MODEL["ebf"]
    )
    train(cfg)
    return read_checkpoint(tmp_path / name / "checkpoints" / "last.ckpt")


def test_fixed_seed_is_deterministic_and_resume_matches_uninterrupted_run(tmp_path):
    a = _final_state(tmp_path, "a", 2)
    b = _final_state(tmp_path, "b", 2)
    for key, value in a["state_dict"].items():
        torch.testing.assert_close(b["state_dict"][key], value, rtol=0, atol=0)
    first = _final_state(tmp_path, "c", 1)
    assert first["global_step"] == 2
    resumed = _final_state(tmp_path, "c", 2, ckpt_path="last")
    assert resumed["global_step"] == 4 and resumed["epoch"] == 1
    for key, value in a["state_dict"].items():  # killed after epoch 1 and resumed == run straight through
        torch.testing.assert_close(resumed["state_dict"][key], value, rtol=0, atol=0)
    assert resumed["datamodule_hyper_parameters"]["corpus"] == "sample"
    result = json.loads((tmp_path / "c" / "result.json").read_text())
    assert result["monitor"] == "val/angle_err_deg" and Path(result["best"]).exists()


def test_last_checkpoint_is_the_latest_epoch_even_when_validation_stops_improving(tmp_path):
    """With lr=0 the validation score never improves after epoch 0: best.ckpt stays at epoch 0 and last.ckpt
    (what ``ckpt_path=last`` resumes from) must still hold the last epoch trained."""
    cfg = compose_cfg(
        [f"runs_root={tmp_path}", "name=flat", "trainer.max_epochs=3", "model.lr=0.0"] + QUICK + TINY_MODEL["ebf"]
    )
    train(cfg)
    ckpts = tmp_path / "flat" / "checkpoints"
    assert read_checkpoint(ckpts / "best.ckpt")["epoch"] == 0
    last = read_checkpoint(ckpts / "last.ckpt")
    assert last["epoch"] == 2 and last["global_step"] == 6
    assert sorted(p.name for p in ckpts.iterdir()) == ["best.ckpt", "last.ckpt"]


def test_init_from_starts_a_new_run_from_another_runs_weights(tmp_path):
    """A warm restart with lr=0 (another learning rate: allowed) must end with exactly the weights it started
    from (fresh optimizer and schedule, same tensors), also from a checkpoint carrying an inference setting
    (``change_limit``, as the shipped ones do); weights of another size or network are refused naming the key or
    class, a missing file before any data is set up."""
    source = _final_state(tmp_path, "source", 1)["state_dict"]
    start = tmp_path / "source" / "checkpoints" / "last.ckpt"
    cfg = compose_cfg(
        [f"runs_root={tmp_path}", "name=warm", "trainer.max_epochs=1", "model.lr=0.0", f"init_from={start}"]
        + QUICK
        + TINY_MODEL["ebf"]
    )
    train(cfg)
    warm = read_checkpoint(tmp_path / "warm" / "checkpoints" / "last.ckpt")
    assert warm["global_step"] == 2  # a new run: its own steps, not the source's continued
    for key, value in source.items():
        torch.testing.assert_close(warm["state_dict"][key], value, rtol=0, atol=0)
    shipped_like = read_checkpoint(start)
    shipped_like["hyper_parameters"]["change_limit"] = 2.5  # set at export for inference only
    torch.save(shipped_like, tmp_path / "shipped_like.ckpt")
    again = compose_cfg(
        [f"runs_root={tmp_path}", "name=again", "trainer.max_epochs=1", "model.lr=0.0"]
        + [f"init_from={tmp_path / 'shipped_like.ckpt'}"]
        + QUICK
        + TINY_MODEL["ebf"]
    )
    train(again)
    wider = compose_cfg(
        [f"runs_root={tmp_path}", "name=wider", "trainer.max_epochs=1", f"init_from={start}", "model.hidden=12"]
        + QUICK
        + TINY_MODEL["ebf"][1:]
    )
    with pytest.raises(MocapFileError, match="trained with hidden=8, this run has hidden=12"):
        train(wider)
    other = compose_cfg(
        [f"runs_root={tmp_path}", "name=other", "model=ebd", "corruption=gaps", f"init_from={start}"]
        + QUICK
        + TINY_MODEL["ebd"]
    )
    with pytest.raises(MocapFileError, match="holds EBF weights, this run trains EBD"):
        train(other)
    assert not (tmp_path / "wider" / "checkpoints").exists() and not (tmp_path / "other" / "checkpoints").exists()
    missing = compose_cfg([f"runs_root={tmp_path}", "name=missing", f"init_from={tmp_path / 'nope.ckpt'}"] + QUICK)
    with pytest.raises(FileNotFoundError, match="nope.ckpt"):
        train(missing)
    assert not (tmp_path / "missing").exists()


def test_mocapnet_train_runs_in_process_and_writes_under_the_cwd(tmp_path, monkeypatch, capsys):
    from mocapnet.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MOCAPNET_RUNS", raising=False)
    quick = [o for o in QUICK if o != "data=sample"] + TINY_MODEL["ebf"] + ["trainer.max_epochs=1"]
    assert main(["train", "experiment=sample_quick", *quick]) == 0
    best = tmp_path / "runs" / "sample_quick" / "checkpoints" / "best.ckpt"
    assert best.exists() and str(best.relative_to(tmp_path)) in capsys.readouterr().out


@pytest.mark.parametrize("override", ["experiment=no_such_experiment", "trainer.no_such_key=1", "model=zzz"])
def test_bad_training_override_is_a_one_line_error(override, tmp_path, monkeypatch, capsys):
    from mocapnet.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["train", override]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocapnet: error: training config:") and err.count("\n") == 1
    assert not (tmp_path / "runs").exists()


def test_cosine_schedule_decays_within_the_budget_and_checkpoints_stay_plain(tmp_path):
    cfg = compose_cfg(
        [f"runs_root={tmp_path}", "name=cos", "trainer.max_epochs=2", "model.lr_schedule=cosine", "model.lr=0.01"]
        + QUICK
        + TINY_MODEL["ebf"]
    )
    train(cfg)
    last = read_checkpoint(tmp_path / "cos" / "checkpoints" / "last.ckpt")
    lr = last["optimizer_states"][0]["param_groups"][0]["lr"]
    assert type(lr) is float and 0.01 / 50 <= lr < 0.01
    model = EBF(6, lr=0.01, lr_schedule="cosine")
    values = [model.scheduled_lr(f) for f in (0.0, 0.02, 0.5, 1.0)]
    assert (
        values[0] < values[1] == pytest.approx(0.01)
        and values[2] == pytest.approx(0.0002 + 0.0049 * (1 + math.cos(math.pi * 0.48 / 0.98)))
        and values[3] == 0.0002
    )


def test_data_and_model_must_agree_on_the_gap_interpolation():
    from mocapnet.nn.train import build, compose_config

    cfg = compose_config(["experiment=sample_quick", "model=ebd", "+data.spline_max_s=0.5"])
    with pytest.raises(ValueError, match="spline_max_s"):
        build(cfg)


def test_ema_checkpoints_hold_the_averaged_weights_and_resume(tmp_path):
    """With ``ema_decay`` the checkpoint's state_dict is the average (not the raw weights, kept beside it for
    resuming); a resumed run continues the average; a bad decay is refused before anything is written."""
    base = [f"runs_root={tmp_path}", "name=ema", "ema_decay=0.5"] + QUICK + TINY_MODEL["ebf"]
    train(compose_cfg(base + ["trainer.max_epochs=1"]))
    for name in ("last.ckpt", "best.ckpt"):
        first = read_checkpoint(tmp_path / "ema" / "checkpoints" / name)
        raw, averaged = first["current_model_state"], first["state_dict"]
        assert raw.keys() == averaged.keys()
        weights = [k for k in raw if raw[k].is_floating_point() and "encoder" in k]
        assert weights and any(not torch.equal(raw[k], averaged[k]) for k in weights)
        for buffer in ("center", "scale", "angvel_scale"):  # the normaliser is not averaged
            assert torch.equal(raw[buffer], averaged[buffer])
    train(compose_cfg(base + ["trainer.max_epochs=2"]))
    resumed = read_checkpoint(tmp_path / "ema" / "checkpoints" / "last.ckpt")
    assert resumed["global_step"] == 4 and int(resumed["averaging_state"]["n_averaged"]) == 4
    model = EBF.load_from_checkpoint(tmp_path / "ema" / "checkpoints" / "last.ckpt", weights_only=True)
    torch.testing.assert_close(model.state_dict()[weights[0]], resumed["state_dict"][weights[0]])
    for bad in ("1.5", "abc"):
        with pytest.raises(ValueError, match="ema_decay"):
            train(compose_cfg([f"runs_root={tmp_path}", "name=bad", f"ema_decay={bad}"] + QUICK))
    assert not (tmp_path / "bad").exists()
    without = [o for o in base if o != "ema_decay=0.5"] + ["trainer.max_epochs=3"]
    with pytest.raises(MocapFileError, match="written with ema_decay"):  # resuming must keep the setting
        train(compose_cfg(without))
