"""Clean one file: read it, run a method, check, write the result. Used by ``mocapnet clean`` (one file or a
folder) so a batch clean is the one-file clean, bit for bit."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapnet.io.atomic import MocapFileError

BVH_SUFFIXES = (".bvh", ".bvh.gz")
C3D_SUFFIXES = (".c3d",)


@dataclass(frozen=True)
class CleanOptions:
    """What to do with each file; ``None`` picks the default for the file's format."""

    method: str | None = None
    model: str | None = None
    mask: str | None = None
    database: str | None = None
    plot: str | None = None  # C3D: PNG of the filled markers' trajectories
    allow_truncated: bool = False  # C3D: read the frames present in a truncated file (warning) instead of failing


@dataclass(frozen=True)
class CleanResult:
    """What one clean did: ``samples_filled`` counts missing samples given a value; ``details`` holds
    method-specific JSON-able facts (e.g. a per-gap report under ``"gaps"``)."""

    source: Path
    output: Path
    method: str
    frames: int
    samples_filled: int
    message: str
    details: dict = field(default_factory=dict)


def file_format(path: str | os.PathLike) -> str:
    """``'bvh'`` or ``'c3d'`` from the file name (case-insensitive); ``MocapFileError`` for anything else."""
    name = Path(path).name.lower()
    if name.endswith(BVH_SUFFIXES):
        return "bvh"
    if name.endswith(C3D_SUFFIXES):
        return "c3d"
    raise MocapFileError(f"{path}: unknown file type (expected .bvh, .bvh.gz or .c3d)")


def check_output_name(src: str | os.PathLike, out: str | os.PathLike) -> None:
    """Refuse an output whose format (by extension, case-insensitive) differs from the input's or is missing."""
    want = file_format(src)
    if not str(out).strip():
        raise MocapFileError(f"output path is empty (input {src})")
    try:
        got = file_format(out)
    except MocapFileError:
        got = None
    if got != want:
        ext = ".bvh or .bvh.gz" if want == "bvh" else ".c3d"
        raise MocapFileError(f"{out}: output name must end in {ext} for a {want.upper()} input {src}")
    if Path(out).resolve() == Path(src).resolve():
        raise MocapFileError(f"{out}: output path is the same as the input; choose another output file")


def read_mask(path: str | os.PathLike, motion) -> np.ndarray:
    """Read a missing-sample mask for ``motion``: ``.npy`` of bool or 0/1 integers, ``[T, C]`` or ``[T, J]``.

    Returns a bool ``[T, C]`` mask (True = missing); a ``[T, J]`` mask marks every channel of a joint, its
    position channels and the root's included. Anything else (floats, NaN, strings, objects, an empty array, a
    pickle, an ``.npz`` archive) raises ``MocapFileError`` naming the file.
    """
    if not Path(path).is_file():
        raise MocapFileError(f"{path}: no such mask file")
    try:
        raw = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise MocapFileError(f"{path}: not a NumPy .npy mask ({exc})") from exc
    if isinstance(raw, np.lib.npyio.NpzFile):
        raw.close()
        raise MocapFileError(f"{path}: an .npz archive; save the mask with np.save as a single .npy array")
    if raw.size == 0:
        raise MocapFileError(f"{path}: the mask is empty (shape {raw.shape})")
    if raw.dtype == bool:
        mask = raw
    elif np.issubdtype(raw.dtype, np.integer) and np.isin(raw, (0, 1)).all():
        mask = raw.astype(bool)
    else:
        raise MocapFileError(f"{path}: mask must hold bool or 0/1 integers (True/1 = missing), got dtype {raw.dtype}")
    sk = motion.skeleton
    if mask.shape == (motion.n_frames, sk.n_joints):
        return mask[:, np.repeat(np.arange(sk.n_joints), np.diff(sk.channel_offsets))]
    if mask.shape != motion.channels.shape:
        raise MocapFileError(
            f"{path}: mask shape {mask.shape} fits neither [T, C] = {motion.channels.shape} "
            f"nor [T, J] = {(motion.n_frames, sk.n_joints)}"
        )
    return mask


def clean_bvh_file(src: Path, out: Path, options: CleanOptions) -> CleanResult:
    """Denoise (and with a mask, fill) a BVH file with a joint-angle method and write the result. The default
    (``auto``, ``mocapnet.methods.auto_angles``): the networks shipped for the skeleton, else ``gaussian-cv``;
    the result's message and ``details["auto"]`` say which and why."""
    from mocapnet.branches import StoredBranches
    from mocapnet.io import read_bvh, write_bvh
    from mocapnet.methods.registry import MethodSpec, build_method

    stored = read_bvh(src, unwrap=False)
    mask = read_mask(options.mask, stored) if options.mask else np.zeros(stored.channels.shape, dtype=bool)
    # rotations made continuous (wraps and Euler flips) without reading the masked placeholders; put back at the end
    branches, continuous = StoredBranches.of(stored.channels, mask, stored.skeleton)
    motion = stored.with_channels(continuous)
    method, why = options.method, ""
    if method is None and options.model:
        method = "ebd+ebf" if mask.any() else "ebf"
    if method is None or method.strip() == "auto":
        if options.model:
            raise ValueError(
                "--model names a checkpoint for a network method: give --method too (ebf, ebd, ebd+ebf, ...)"
            )
        from mocapnet.methods.auto_angles import auto_plan

        method, why = auto_plan(motion.skeleton, motion.fps, bool(mask.any()))
    if options.model:  # the checkpoints replaced, the method's options kept
        method = MethodSpec.parse(method).with_checkpoints(options.model.split(",")).canonical()
    built = build_method(method, space="angles")
    # the methods fill scored rotations; the root's and other unscored channels' gaps are interpolated linearly
    unscored = mask & ~motion.skeleton.scored_mask
    if unscored.any():
        from mocapnet.fill import lerp_fill

        motion = motion.with_channels(lerp_fill(np.where(unscored, np.nan, motion.channels), unscored))
        _check_filled(motion.channels, unscored, options.mask, "linear interpolation", motion.skeleton, "")
    noisy = motion.channels.copy()
    noisy[mask & ~unscored] = np.nan
    cleaned = built.clean(motion.with_channels(noisy), mask & ~unscored)
    _check_filled(
        cleaned, mask, options.mask, method, motion.skeleton, ", or use ebd where one is shipped for the skeleton"
    )
    write_bvh(out, motion.with_channels(branches.restore(cleaned)), inputs=(src,))
    n_missing, n_linear = int(mask.sum()), int(unscored.sum())
    # before a channel's first observed sample or after its last, interpolation can only hold the nearest value
    observed = np.cumsum(~unscored, axis=0)
    n_held = int((unscored & ((observed == 0) | (observed == observed[-1]))).sum())
    held = f" ({n_held} at the clip's ends held at the nearest observed value)" if n_held else ""
    linear = f", {n_linear} of them in unscored channels (root, positions, context joints) filled linearly{held}"
    return CleanResult(
        src, out, method, motion.n_frames, n_missing,
        f"{src} -> {out}: {method} on {motion.n_frames} frames ({n_missing} missing samples"
        + (linear if n_linear else "") + ")" + (f"; auto: {why}" if why else ""),
        ({"auto": why} if why else {})
        | ({"filled_linearly": n_linear, "held_at_ends": n_held} if n_linear else {}),
    )  # fmt: skip


def _check_filled(values: np.ndarray, mask: np.ndarray, mask_path: str | None, how: str, skeleton, other: str) -> None:
    """ValueError naming the mask file, the first channel and frame ``how`` left missing (e.g. a channel masked in
    every frame: nothing to interpolate from), with ``other`` ways out appended to the advice; nothing is written
    then."""
    unfilled = mask & ~np.isfinite(values)
    if unfilled.any():
        t, c = np.argwhere(unfilled)[0]
        label = skeleton.channel_labels[c]
        whole = " (masked in every frame)" if mask[:, c].all() else ""
        raise ValueError(
            f"{mask_path}: {how} cannot fill {label}{whole}: {int(unfilled[:, c].sum())} samples left missing "
            f"from frame {t + 1}; unmask some of its frames{other}"
        )


def clean_c3d_file(src: Path, out: Path, options: CleanOptions) -> CleanResult:
    """Fill the gaps of a C3D file's markers (or, with a smoother, denoise its measured samples) and write the
    result.

    The default method ``auto`` (``mocapnet.methods.autofill``) chooses a filler per gap, checks each fill
    and leaves gaps it cannot fill plausibly missing; another ``--method`` fills every gap it can. Either
    way ``details["gaps"]`` holds one JSON-able report per gap (marker, frames, method, step ratio, status)
    and ``options.plot`` names a PNG of the filled markers to write. A smoother (``gaussian-cv``: its clean
    function has ``moves_measured``) moves measured samples instead; they are written with their residual and
    camera words kept (``write_c3d(moved=...)``), its gaps stay missing, ``details["smoothed_samples"]`` counts
    the samples whose stored position changed.
    """
    from mocapnet.io import read_c3d, write_c3d
    from mocapnet.methods.autofill import auto_fill, describe_fill, plot_fills
    from mocapnet.methods.registry import MethodContext, build_method, parse_method
    from mocapnet.motion import Markers

    markers = read_c3d(src, allow_truncated=options.allow_truncated)
    method = options.method or "auto"
    name, method_options = parse_method(method)
    usable = np.flatnonzero(markers.visible.any(axis=0))
    n_missing = int((~markers.visible[:, usable]).sum())
    smoother = False
    if name == "auto":
        database = method_options.pop("database", options.database)
        try:
            got = auto_fill(markers, database=database, **method_options)
        except TypeError as exc:
            raise ValueError(f"method {method!r}: {exc}") from exc
        points, gaps = got.points, got.gaps
    else:
        if options.database and name == "knn" and "database" not in method_options:
            method += (":" if ":" not in method else ",") + f"database={options.database}"
        built = build_method(method, MethodContext(corruption="file gaps"), space="points")
        smoother = bool(getattr(built.clean, "moves_measured", False))
        if smoother and options.plot:
            raise ValueError(f"--plot draws the filled gaps; {name} fills none (it moves measured samples)")
        points = markers.points.copy()
        if n_missing or smoother:
            points[:, usable] = built.clean(markers.select(usable))
        gaps = [] if smoother else describe_fill(markers, points, name)
    filled = np.isfinite(points).all(axis=2) & ~markers.visible
    moved = None
    if smoother:
        moved = markers.visible & np.isfinite(points).all(axis=2) & (points != markers.points).any(axis=2)
    result = Markers(points, markers.visible | filled, markers.labels, markers.fps, markers.name)
    write_c3d(out, result, inputs=(src,), source=src, filled=filled, moved=moved)
    if moved is not None:  # count what the file now holds (an integer file rounds small moves away)
        back = read_c3d(out, allow_truncated=options.allow_truncated)
        moved = moved & (back.points != markers.points).any(axis=2)
    if options.plot:
        plot_fills(options.plot, markers, points, gaps)
    empty = markers.n_markers - usable.size
    n_filled = int(filled.sum())
    left = sum(bool(g["unfilled_spans"]) for g in gaps)
    done = (
        f"smoothed {int(moved.sum())} measured samples of {usable.size} markers (residuals kept; "
        f"{n_missing} missing samples left missing)"
        if moved is not None
        else f"filled {n_filled} of {n_missing} missing samples in {usable.size} markers"
    )
    return CleanResult(
        src, out, method, markers.n_frames, n_filled,
        f"{src} -> {out}: {method} {done}"
        + (f" (read with {reader})" if (reader := getattr(markers, "reader", "ezc3d")) != "ezc3d" else "")
        + (f"; {left} gaps wholly or partly left missing (no plausible fill)" if left and moved is None else "")
        + (f"; knn database: {built.clean.database}" if name == "knn" else "")
        + (f"; {empty} markers with no data at all left empty" if empty else ""),
        {"gaps": gaps, "file_first_frame": markers.first_frame}
        | ({"smoothed_samples": int(moved.sum())} if moved is not None else {}),
    )  # fmt: skip


def clean_file(src: str | os.PathLike, out: str | os.PathLike, options: CleanOptions) -> CleanResult:
    """Clean one BVH or C3D file into ``out`` (same format; written atomically, never over ``src``)."""
    src, out = Path(src), Path(out)
    check_output_name(src, out)
    if file_format(src) == "c3d":
        return clean_c3d_file(src, out, options)
    return clean_bvh_file(src, out, options)
