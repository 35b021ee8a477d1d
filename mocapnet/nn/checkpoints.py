"""Checkpoints shipped in the package (``mocapnet/checkpoints/``) and their index.

``index.json`` lists, per file: the method it serves (an EBF variant ``ebf-paper``/``ebf-bias``/``ebf-free``,
``ebd``, ``bf``, ``nn``; ``"ebf": true`` marks the variant ``ebf`` runs for that skeleton), the corpus it was
trained on, the skeleton topology hash it applies to (``features.topology_hash``), the skeleton's description,
the frame rate, the validation score and the command that trained it. Shipped files are slimmed training
checkpoints (weights, hyper-parameters, normaliser; no optimiser state), still loadable with
``EBF.load_from_checkpoint``.

Checkpoints are data, never code: every load goes through ``read_checkpoint``, which uses
``torch.load(weights_only=True)`` (tensors, numbers, strings, lists, dicts: PyTorch's restricted unpickler,
extended only by ``ALLOWED_GLOBALS``, numpy scalars) and refuses anything else with ``MocapFileError``. A shipped
checkpoint is also checked against the SHA-256 recorded for it in ``index.json``.

An ``ebd`` entry may name a short-gap partner, ``"short": {"file": ..., "max_s": ...}``: another shipped EBD of the
same skeleton and frame rate that fills the gaps shorter than ``max_s`` seconds (``shipped_short``); the partner's
entry says ``"short_for": FILE`` and serves no method by itself (``variants.serves``).

Export a trained run::

    python -m mocapnet.nn.checkpoints RUN/checkpoints/best.ckpt bandai2_ebf --command "python scripts/train.py ..."
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import re
import zipfile
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mocapnet.io.atomic import MocapFileError
from mocapnet.motion import Skeleton
from mocapnet.nn import variants
from mocapnet.nn.features import topology_hash
from mocapnet.nn.variants import EBF_VARIANTS, SHORT_MAX_S, serves

CHECKPOINT_DIR = Path(__file__).resolve().parents[1] / "checkpoints"
INDEX = CHECKPOINT_DIR / "index.json"
#: The allow-list: what a checkpoint may hold besides tensors and plain values. Numpy scalars (a dtype and
#: its bytes; e.g. a learning rate Lightning copied from a numpy computation) are data; nothing else is.
_MULTIARRAY = np._core.multiarray if hasattr(np, "_core") else np.core.multiarray
ALLOWED_GLOBALS = [np.dtype, _MULTIARRAY.scalar, *{type(np.dtype(code)) for code in "?bhilqBHILQefdgFDG"}]
_NORMALISER = ("center", "scale", "angvel_scale")  # buffers kept in float32 by ``export(fp16=True)``
_KEEP = (
    "state_dict",
    "hyper_parameters",
    "hparams_name",
    "pytorch-lightning_version",
    "mocapnet_model",
    "epoch",
    "global_step",
)


def sha256_of(path: str | PathLike) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _shipped_entry(path: Path) -> dict[str, Any] | None:
    """The index entry of ``path`` when it is a file in ``CHECKPOINT_DIR``, else None."""
    if path.resolve().parent != CHECKPOINT_DIR:
        return None
    return next((e for e in read_index() if e["file"] == path.name), None)


def read_checkpoint(path: str | PathLike) -> dict[str, Any]:
    """Load a checkpoint file as data (``torch.load(weights_only=True)``, on the CPU) and return its dict.

    Raises FileNotFoundError when there is no such file, and MocapFileError naming the file when it is not
    a readable PyTorch checkpoint (truncated, foreign format), when it needs any object beyond tensors and
    plain values to load (such a file could run code: it is refused, nothing in it runs), when it is not a
    dict, or when it is a shipped checkpoint whose SHA-256 differs from the one in ``index.json``.
    """
    src = Path(path)
    if not src.is_file():
        raise FileNotFoundError(f"checkpoint {src} not found")
    entry = _shipped_entry(src)
    if entry is not None and entry.get("sha256") and sha256_of(src) != entry["sha256"]:
        raise MocapFileError(
            f"{src}: SHA-256 differs from the one recorded in {INDEX.name}; the shipped checkpoint was changed "
            "or damaged (reinstall mocapnet)"
        )
    try:
        with torch.serialization.safe_globals(ALLOWED_GLOBALS):
            ckpt = torch.load(src, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        inner = str(exc.__context__ or exc)
        found = re.search(r"GLOBAL (\S+)", inner)
        if found is None:
            reason = (inner.strip().splitlines() or [type(exc).__name__])[0][:200]
            raise MocapFileError(f"{src}: not a readable PyTorch checkpoint (truncated or foreign: {reason})") from None
        raise MocapFileError(
            f"{src}: refused: loading it would call {found.group(1)[:80]}, which is not a tensor or plain value; "
            "mocapnet loads checkpoints as data only (torch.load weights_only=True), so nothing in it was run"
        ) from None
    except (RuntimeError, EOFError, OSError, zipfile.BadZipFile, ValueError, KeyError) as exc:
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise MocapFileError(f"{src}: not a readable PyTorch checkpoint (truncated or foreign: {reason})") from None
    if not isinstance(ckpt, dict):
        raise MocapFileError(f"{src}: not a mocapnet checkpoint (holds a {type(ckpt).__name__}, not a dict)")
    return ckpt


def method_of(checkpoint: dict[str, Any]) -> str:
    """The method name a checkpoint serves (``variants.method_of``): an EBF variant, ``bf``, ``ebd`` or ``nn``."""
    return variants.method_of(checkpoint["mocapnet_model"], checkpoint["hyper_parameters"])


def read_index() -> list[dict[str, Any]]:
    return json.loads(INDEX.read_text())["checkpoints"] if INDEX.exists() else []


def _serving_entry(method: str, skeleton: Skeleton) -> dict[str, Any] | None:
    """The index entry that serves ``method`` for ``skeleton``'s topology (``variants.serves``), or None."""
    mine = topology_hash(skeleton)
    return next((e for e in read_index() if serves(e, method) and e["skeleton_hash"] == mine), None)


def shipped_checkpoint(method: str, skeleton: Skeleton) -> Path:
    """The shipped checkpoint of ``method`` for ``skeleton``'s topology; LookupError naming this skeleton and
    the shipped ones when there is none."""
    entry = _serving_entry(method, skeleton)
    if entry is not None:
        return CHECKPOINT_DIR / entry["file"]
    mine = topology_hash(skeleton)
    same = [e for e in read_index() if serves(e, method)]
    shipped = sorted({f"{e['corpus']}: {e['skeleton']} ({e['skeleton_hash']})" for e in same})
    raise LookupError(
        f"no shipped {method!r} checkpoint for this skeleton, {skeleton.describe()} ({mine}); shipped "
        f"{method!r} checkpoints are for: {'; '.join(shipped) or 'none'}. Train one (mocapnet train) and pass "
        f"--method {method}=path.ckpt"
    )


def shipped_short(skeleton: Skeleton) -> tuple[Path, float] | None:
    """The short-gap partner of the shipped ``ebd`` for ``skeleton``'s topology, as (file, longest gap it fills in
    seconds, exclusive): the main entry's ``"short": {"file": ..., "max_s": ...}``; None when it has none or no
    ``ebd`` is shipped for the skeleton."""
    entry = _serving_entry("ebd", skeleton)  # the entry shipped_checkpoint("ebd", ...) names
    if entry is None or not entry.get("short"):
        return None
    return CHECKPOINT_DIR / entry["short"]["file"], float(entry["short"]["max_s"])


def export(
    src: str | PathLike,
    name: str,
    command: str = "",
    metrics: dict[str, float] | None = None,
    recipe: str = "",
    budget: str = "",
    as_ebf: bool = False,
    fp16: bool = False,
    short: str | None = None,
    short_max_s: float = SHORT_MAX_S,
) -> Path:
    """Slim ``src`` into ``mocapnet/checkpoints/<name>.ckpt`` and record it in ``index.json`` (replacing an
    entry of the same file name) with its SHA-256, ``recipe`` (how it was trained, in words) and ``budget``
    (wall-clock training time). ``as_ebf``: this EBF variant becomes what ``ebf`` runs for its skeleton.
    ``fp16``: store the weights in half precision (half the bytes; loading casts them back to float32), the
    normaliser buffers stay float32. ``short``: the file name of a shipped EBD of the same skeleton that fills
    this EBD's gaps shorter than ``short_max_s`` seconds (``shipped_short``; it is marked ``"short_for"`` and
    serves no method itself). Nothing is written when a check fails."""
    from mocapnet.corpus import load_corpus

    ckpt = read_checkpoint(src)
    slim = {k: ckpt[k] for k in _KEEP if k in ckpt}
    if fp16:
        slim["state_dict"] = {
            k: v.half() if v.is_floating_point() and k not in _NORMALISER else v for k, v in slim["state_dict"].items()
        }
    hp = slim["hyper_parameters"]
    skeleton = load_corpus(hp["corpus"], progress=False).motions[0].skeleton
    if topology_hash(skeleton) != hp["skeleton_hash"]:
        raise ValueError(f"{src}: skeleton hash {hp['skeleton_hash']} does not match corpus {hp['corpus']!r}")
    dst = CHECKPOINT_DIR / f"{name}.ckpt"
    _check_export(method_of(slim), hp, dst.name, as_ebf, short, short_max_s)  # before anything is written
    CHECKPOINT_DIR.mkdir(parents=True, exist_ok=True)
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
        "val_corruptions": list(ckpt.get("datamodule_hyper_parameters", {}).get("val_corruptions", [])),
        "weights": "float16" if fp16 else "float32",
        "epochs": None if slim.get("epoch") is None else int(slim["epoch"]) + 1,
        "bytes": dst.stat().st_size,
        "sha256": sha256_of(dst),
        "recipe": recipe,
        "budget": budget,
        "command": command,
        **(metrics or {}),
    }
    if as_ebf:
        entry["ebf"] = True
    if short is not None:
        entry["short"] = {"file": short, "max_s": float(short_max_s)}
    old = next((e for e in read_index() if e["file"] == dst.name), {})
    if old.get("short_for"):  # re-exported as what it was: another EBD's short-gap partner
        entry["short_for"] = old["short_for"]
    others = [e for e in read_index() if e["file"] != dst.name]
    for e in others:
        if as_ebf and e["skeleton_hash"] == entry["skeleton_hash"]:
            e.pop("ebf", None)
        if e["file"] == short:
            e["short_for"] = dst.name
    entries = others + [entry]
    INDEX.write_text(json.dumps({"checkpoints": sorted(entries, key=lambda e: e["file"])}, indent=1) + "\n")
    return dst


def _check_export(
    method: str, hp: dict[str, Any], file: str, as_ebf: bool, short: str | None, short_max_s: float
) -> None:
    """ValueError when ``export`` of a ``method`` network (hyper-parameters ``hp``) as ``file`` would leave the
    index wrong or ambiguous: ``as_ebf`` on a network that is no EBF variant, a ``short`` partner that is not a
    shipped, unpaired EBD of the same skeleton and frame rate (or a length that is not a finite time > 0), or a
    second network serving ``method`` for the skeleton."""
    entries = {e["file"]: e for e in read_index()}
    if as_ebf and method not in EBF_VARIANTS:
        raise ValueError(f"{file}: a {method} checkpoint cannot serve 'ebf'")
    if as_ebf and hp.get("deltas", "off") != "off":
        raise ValueError(f"{file}: a network with delta inputs cannot serve 'ebf' (it cannot stream)")
    if short is not None:
        partner = entries.get(short) if short != file else None
        checks = [
            (method == "ebd", f"this network is {method}, not an EBD"),
            (partner is not None, "it is not in index.json"),
            (partner is not None and partner["method"] == "ebd", "it is no EBD"),
            (partner is not None and partner["skeleton_hash"] == hp["skeleton_hash"], "it is for another skeleton"),
            (partner is not None and float(partner["fps"]) == float(hp["fps"]), "it is for another frame rate"),
            (partner is not None and not partner.get("short"), "it has a short-gap network of its own"),
            (partner is not None and partner.get("short_for") in (None, file), "it is another EBD's partner"),
            (bool(np.isfinite(short_max_s) and short_max_s > 0), f"short_max_s {short_max_s!r} is not a time > 0 s"),
        ]
        problems = [why for ok, why in checks if not ok]
        if problems:
            raise ValueError(
                f"--short {short}: a short-gap partner must be a shipped EBD of this skeleton: {problems[0]}"
            )
    if entries.get(file, {}).get("short_for"):  # a partner re-exported stays a partner, serving nothing
        return
    for e in entries.values():
        same = e["method"] == method and e["skeleton_hash"] == hp["skeleton_hash"]
        if same and e["file"] not in (file, short) and not e.get("short_for"):
            raise ValueError(
                f"{file}: index.json already ships {method} for this skeleton as {e['file']}; export under that "
                "name to replace it (or remove its entry first)"
            )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Ship a trained checkpoint in mocapnet/checkpoints/ (slimmed).")
    parser.add_argument("checkpoint", help="training checkpoint, e.g. runs/bandai2_ebf/checkpoints/best.ckpt")
    parser.add_argument("name", help="file name without .ckpt, e.g. bandai2_ebf")
    parser.add_argument("--command", default="", help="the training command, recorded in index.json")
    parser.add_argument("--recipe", default="", help="how it was trained, in words, recorded in index.json")
    parser.add_argument("--budget", default="", help="wall-clock training budget, e.g. '70 min on 1 CPU thread'")
    parser.add_argument("--ebf", action="store_true", help="make this EBF variant the one `ebf` runs")
    parser.add_argument("--fp16", action="store_true", help="store the weights in half precision")
    parser.add_argument(
        "--short",
        default=None,
        metavar="FILE",
        help="a shipped EBD (file name, e.g. bandai2_ebd_short.ckpt) that fills this EBD's short gaps",
    )
    parser.add_argument(
        "--short-max-s", type=float, default=SHORT_MAX_S, help="the gaps --short fills: shorter than this (s)"
    )
    args = parser.parse_args(argv)
    options = {"recipe": args.recipe, "budget": args.budget, "as_ebf": args.ebf, "fp16": args.fp16}
    options |= {"short": args.short, "short_max_s": args.short_max_s}
    print(export(args.checkpoint, args.name, args.command, **options))


if __name__ == "__main__":
    main()
