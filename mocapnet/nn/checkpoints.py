"""Checkpoints shipped in the package (``mocapnet/checkpoints/``) and their index.

``index.json`` lists, per file: the method it serves (``ebf``, ``ebd``, ``bf``, ``nn``), the corpus it was
trained on, the skeleton topology hash it applies to (``features.topology_hash``), the skeleton's description,
the frame rate, the validation score and the command that trained it. Shipped files are slimmed training
checkpoints (weights, hyper-parameters, normaliser; no optimiser state), still loadable with
``EBF.load_from_checkpoint``.

Export a trained run::

    python -m mocapnet.nn.checkpoints RUN/checkpoints/best.ckpt bandai2_ebf --command "python scripts/train.py ..."
"""

from __future__ import annotations

import argparse
import json
from os import PathLike
from pathlib import Path
from typing import Any

import torch

from mocapnet.motion import Skeleton
from mocapnet.nn.features import topology_hash

CHECKPOINT_DIR = Path(__file__).resolve().parents[1] / "checkpoints"
INDEX = CHECKPOINT_DIR / "index.json"
_KEEP = (
    "state_dict",
    "hyper_parameters",
    "hparams_name",
    "pytorch-lightning_version",
    "mocapnet_model",
    "epoch",
    "global_step",
)


def method_of(checkpoint: dict[str, Any]) -> str:
    """The method name a checkpoint serves: ``ebf``, ``bf`` (EBF without encoder), ``ebd`` or ``nn``."""
    kind = checkpoint["mocapnet_model"]
    if kind == "EBF":
        return "ebf" if checkpoint["hyper_parameters"]["encoder_layers"] else "bf"
    return {"EBD": "ebd", "WindowMLP": "nn"}[kind]


def read_index() -> list[dict[str, Any]]:
    return json.loads(INDEX.read_text())["checkpoints"] if INDEX.exists() else []


def shipped_checkpoint(method: str, skeleton: Skeleton) -> Path:
    """The shipped checkpoint of ``method`` for ``skeleton``'s topology; LookupError naming this skeleton and
    the shipped ones when there is none."""
    mine = topology_hash(skeleton)
    entries = read_index()
    for entry in entries:
        if entry["method"] == method and entry["skeleton_hash"] == mine:
            return CHECKPOINT_DIR / entry["file"]
    same = [e for e in entries if e["method"] == method]
    shipped = sorted({f"{e['corpus']}: {e['skeleton']} ({e['skeleton_hash']})" for e in same})
    raise LookupError(
        f"no shipped {method!r} checkpoint for this skeleton, {skeleton.describe()} ({mine}); shipped "
        f"{method!r} checkpoints are for: {'; '.join(shipped) or 'none'}. Train one (scripts/train.py) and pass "
        f"--method {method}=path.ckpt"
    )


def export(src: str | PathLike, name: str, command: str = "", metrics: dict[str, float] | None = None) -> Path:
    """Slim ``src`` into ``mocapnet/checkpoints/<name>.ckpt`` and record it in ``index.json`` (replacing an
    entry of the same file name)."""
    from mocapnet.corpus import load_corpus

    ckpt = torch.load(src, map_location="cpu", weights_only=False)
    slim = {k: ckpt[k] for k in _KEEP if k in ckpt}
    hp = slim["hyper_parameters"]
    skeleton = load_corpus(hp["corpus"], progress=False).motions[0].skeleton
    if topology_hash(skeleton) != hp["skeleton_hash"]:
        raise ValueError(f"{src}: skeleton hash {hp['skeleton_hash']} does not match corpus {hp['corpus']!r}")
    CHECKPOINT_DIR.mkdir(parents=True, exist_ok=True)
    dst = CHECKPOINT_DIR / f"{name}.ckpt"
    torch.save(slim, dst)
    states = [v for k, v in ckpt.get("callbacks", {}).items() if "ModelCheckpoint" in k]
    score = states[0].get("best_model_score") if states else None
    entry = {
        "file": dst.name,
        "method": method_of(slim),
        "class": slim["mocapnet_model"],
        "corpus": hp["corpus"],
        "skeleton_hash": hp["skeleton_hash"],
        "skeleton": skeleton.describe(),
        "fps": hp["fps"],
        "scored_channels": hp["n_channels"],
        "epoch": slim.get("epoch"),
        "global_step": slim.get("global_step"),
        "val_metric": "val/gap_err_deg" if slim["mocapnet_model"] == "EBD" else "val/angle_err_deg",
        "val_score": None if score is None else round(float(score), 4),
        "bytes": dst.stat().st_size,
        "command": command,
        **(metrics or {}),
    }
    entries = [e for e in read_index() if e["file"] != dst.name] + [entry]
    INDEX.write_text(json.dumps({"checkpoints": sorted(entries, key=lambda e: e["file"])}, indent=1) + "\n")
    return dst


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Ship a trained checkpoint in mocapnet/checkpoints/ (slimmed).")
    parser.add_argument("checkpoint", help="training checkpoint, e.g. runs/bandai2_ebf/checkpoints/best.ckpt")
    parser.add_argument("name", help="file name without .ckpt, e.g. bandai2_ebf")
    parser.add_argument("--command", default="", help="the training command, recorded in index.json")
    args = parser.parse_args(argv)
    print(export(args.checkpoint, args.name, args.command))


if __name__ == "__main__":
    main()
