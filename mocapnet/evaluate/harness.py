"""The evaluation harness: corrupt clean clips reproducibly, run methods, score them (PROTOCOL.md).

BVH data (a corpus name or folder) is scored in angle space; point methods (kNN, extrapolation) run on its
joint positions and are taken back to angles by IK. A folder of C3D files is scored in point space with
``segment-gap`` / ``marker-gap`` corruptions.
"""

from __future__ import annotations

import operator
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mocapnet.corpus import Corpus, load_corpus, style_label
from mocapnet.corrupt import Corruption, corrupt_markers, corrupt_motion, seed_for
from mocapnet.evaluate import metrics
from mocapnet.fill import lerp_fill
from mocapnet.io.atomic import MocapFileError
from mocapnet.io.c3d import read_c3d
from mocapnet.kinematics import global_transforms, inverse_kinematics, local_rotations, motion_points
from mocapnet.methods.registry import Method, MethodContext, MethodSpec, build_method, spaces_of
from mocapnet.motion import Markers, Motion

if TYPE_CHECKING:
    from mocapnet.parallel import Parallel

ROW_FIELDS = (
    "method",
    "corruption",
    "file",
    "repeat",
    "angle_err_deg",
    "gap_err_deg",
    "rot_err_deg",
    "pos_err_cm",
    "point_err_cm",
    "frames",
    "seconds",
)
GAUSSIANS = ("gaussian-58ms", "gaussian-125ms", "gaussian-tuned")
# Test-only corpora (PROTOCOL.md: never train, tune or select on them): their gaussian-tuned reference tunes on
# the corpus named here instead of on their own training folds.
TUNE_ELSEWHERE = {"bandai1": "bandai2"}
INTERPOLATIONS = ("lerp", "spline")
CLIPS_PER_TASK = 8  # clips scored by one Dask task (amortises the per-task overhead)


def has_gaps(corruption: str | Corruption) -> bool:
    """True when the corruption removes samples (``Corruption.has_gaps``)."""
    return Corruption.parse(corruption).has_gaps


@dataclass(frozen=True)
class Reference:
    """The one rule for ratios (PROTOCOL.md 'Ratio'): ``metric`` of a method ÷ the best (lowest) ``metric``
    among ``methods``; ``also`` are baselines every table carries beside them (e.g. the noisy input)."""

    metric: str
    methods: tuple[str, ...]
    also: tuple[str, ...] = ()

    @property
    def carried(self) -> tuple[str, ...]:
        """Every baseline a table of this corruption holds, in table order."""
        return self.also + self.methods


def reference(corruption: str | Corruption, space: str) -> Reference:
    """The reference of a corruption (PROTOCOL.md 'Reference baseline': the best baseline a user could pick):
    the best of the three Gaussians (58 ms, 125 ms, tuned) for noise, the better of lerp and spline for gaps
    (angles or points), lerp + Gaussian 58 ms for ``noise+gaps`` (gaps in noise: fill, then smooth)."""
    c = Corruption.parse(corruption)
    if space == "points":
        return Reference("point_err_cm", INTERPOLATIONS)
    if c.kind == "noise+gaps":
        return Reference("gap_err_deg", ("lerp+gaussian-58ms",), also=("lerp",))
    if c.has_gaps:
        return Reference("gap_err_deg", INTERPOLATIONS)
    return Reference("angle_err_deg", GAUSSIANS, also=("noisy",))


def reference_methods(corruption: str | Corruption, space: str) -> tuple[str, ...]:
    """Baselines every table carries so that ratios can be formed (``reference(...).carried``)."""
    return reference(corruption, space).carried


def corpus_references(corpus: str, corruption: str | Corruption) -> list[str]:
    """The method strings of ``reference_methods`` for a BVH corpus: on a test-only corpus (``TUNE_ELSEWHERE``)
    gaussian-tuned tunes on the other corpus (``gaussian-tuned:tune_on=bandai2``)."""
    elsewhere = TUNE_ELSEWHERE.get(corpus)
    return [
        f"{m}:tune_on={elsewhere}" if m == "gaussian-tuned" and elsewhere else m
        for m in reference_methods(corruption, "angles")
    ]


@dataclass
class Evaluation:
    """Rows (one per method, file, repeat) and what was scored."""

    data: str
    corruption: str
    space: str
    methods: list[str]
    rows: list[dict] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    fold: int | None = None
    repeats: int = 1


def _row(
    method: str, corruption: str | Corruption, file: str, repeat: int, frames: int, seconds: float, **scores: float
) -> dict:
    """One CSV row; metrics not given are NaN."""
    row = {"method": method, "corruption": str(corruption), "file": file, "repeat": repeat}
    row.update({k: float(scores.get(k, float("nan"))) for k in ROW_FIELDS[4:9]})
    row.update(frames=frames, seconds=seconds)
    return row


def is_c3d_data(data: str | Path) -> bool:
    p = Path(str(data))
    if p.is_file():
        return p.suffix.lower() == ".c3d"
    return p.is_dir() and any(f.suffix.lower() == ".c3d" for f in p.iterdir())


# ---------------------------------------------------------------------------------------------- angles


def _points_method_as_angles(method: Method):
    """Run a point method on joint positions and take the result back to angles by IK (masked joints only)."""

    def clean(noisy: Motion, mask: np.ndarray) -> np.ndarray:
        sk = noisy.skeleton
        filled = lerp_fill(noisy.channels, mask)
        base = noisy.with_channels(filled)
        joint_missing = np.stack([mask[:, sk.joint_channels(j)].any(axis=1) for j in range(sk.n_joints)], axis=1)
        # A joint's position depends on its ancestors' rotations: it is missing if any ancestor is.
        pos_missing = joint_missing.copy()
        for j, p in enumerate(sk.parents):
            if p >= 0:
                pos_missing[:, j] |= pos_missing[:, p] | joint_missing[:, p]
        ends_missing = np.stack([pos_missing[:, p] | joint_missing[:, p] for p in sk.end_parents], axis=1)
        visible = ~np.concatenate([pos_missing, ends_missing], axis=1)
        target = method.clean(motion_points(base, visible=visible))
        out = inverse_kinematics(base, target)
        result = noisy.channels.copy()
        result[mask] = out[mask]
        return result

    return clean


def _scored_chunks(
    score: Callable, clips: Sequence, shared: tuple, parallel: Parallel | None, progress: bool, corruption: Corruption
) -> tuple[list[dict], list[tuple[str, str]]]:
    """Run ``score(chunk, *shared) -> (rows, skipped)`` over chunks of ``clips`` (in this process, or on Dask
    with ``parallel``) and concatenate the results in clip order."""
    from mocapnet.parallel import Parallel, map_tasks

    parallel = parallel or Parallel(workers=0)
    size = 1 if parallel.in_process else CLIPS_PER_TASK
    chunks = [list(clips[i : i + size]) for i in range(0, len(clips), size)]
    sizes = [len(c) for c in chunks]
    results = map_tasks(score, chunks, shared, parallel, progress, f"evaluating {corruption}", "clip", sizes)
    rows = [row for chunk_rows, _ in results for row in chunk_rows]
    skipped = [s for _, chunk_skipped in results for s in chunk_skipped]
    return rows, skipped


def score_motions(
    clips: Sequence[Motion],
    built: Sequence[tuple[str, Callable]],
    corpus: str,
    corruption: Corruption,
    repeats: int,
) -> tuple[list[dict], list[tuple[str, str]]]:
    """Rows of every built angle method on ``repeats`` corrupted copies of each clip (seeds from the corpus,
    clip name, repeat and corruption), and the clips skipped with the reason."""
    rows: list[dict] = []
    skipped: list[tuple[str, str]] = []

    def score(motion: Motion, runs: list, truth_rot: np.ndarray, truth_pos: np.ndarray) -> None:
        """Rows of ``runs`` (repeat, method, output, mask, seconds), their pose errors in one batch."""
        sk = motion.skeleton
        pose = metrics.pose_errors_many(motion, [r[2] for r in runs], truth_rot, truth_pos)
        for (rep, text, out, mask, seconds), (rot_err, pos_err) in zip(runs, pose):
            rows.append(
                _row(
                    text, corruption, motion.name, rep, motion.n_frames, seconds,
                    angle_err_deg=metrics.angle_err_deg(out, motion.channels, sk.scored_mask),
                    gap_err_deg=metrics.gap_err_deg(out, motion.channels, mask),
                    rot_err_deg=rot_err,
                    pos_err_cm=pos_err,
                )
            )  # fmt: skip
        runs.clear()

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for motion in clips:
            truth_rot = local_rotations(motion.skeleton, motion.channels)
            truth_pos = global_transforms(motion.skeleton, motion.channels, truth_rot)[1]
            runs: list = []  # outputs waiting to be scored together (at most POSE_BATCH_FRAMES frames)
            for rep in range(repeats):
                rng = np.random.default_rng(seed_for(corpus, motion.name, rep, corruption))
                try:
                    noisy_ch, mask = corrupt_motion(motion, corruption, rng)
                except ValueError as exc:
                    skipped.append((motion.name, str(exc)))
                    break
                noisy = motion.with_channels(noisy_ch)
                for text, clean in built:
                    start = time.perf_counter()
                    out = clean(noisy, mask)
                    runs.append((rep, text, out, mask, time.perf_counter() - start))
                    if len(runs) * motion.n_frames >= metrics.POSE_BATCH_FRAMES:
                        score(motion, runs, truth_rot, truth_pos)
            score(motion, runs, truth_rot, truth_pos)
    return rows, skipped


def evaluate_angles(
    corpus: Corpus,
    clips: Sequence[Motion],
    train: Sequence[Motion],
    corruption: str | Corruption,
    methods: Sequence[str | MethodSpec],
    repeats: int,
    progress: bool = True,
    parallel: Parallel | None = None,
) -> tuple[list[dict], list[tuple[str, str]]]:
    """Score angle-space methods (and point methods through IK) on ``clips``; returns rows and skipped.

    Methods are built (and tuned) once here; ``parallel`` (a ``mocapnet.parallel.Parallel``) scores the clips
    on Dask workers, default in this process. Rows are in clip order either way.
    """
    corruption = Corruption.parse(corruption)
    context = MethodContext(train=train, corpus=corpus.name, corruption=corruption.text)
    point_context: MethodContext | None = None
    built: list[tuple[str, Callable]] = []
    for spec in map(MethodSpec.parse, methods):
        if "angles" in spaces_of(spec.name):
            built.append((str(spec), build_method(spec, context).clean))
            continue
        if point_context is None:
            point_context = MethodContext([motion_points(m) for m in train], corpus.name, corruption.text)
        built.append((str(spec), _points_method_as_angles(build_method(spec, point_context))))
    shared = (built, corpus.name, corruption, repeats)
    return _scored_chunks(score_motions, clips, shared, parallel, progress, corruption)


# ---------------------------------------------------------------------------------------------- points


def load_c3d_folder(data: str | Path, progress: bool = True) -> tuple[list[Markers], list[tuple[str, str]]]:
    """Complete-enough C3D files of a folder (or one file); unreadable files are skipped with the reason."""
    p = Path(str(data))
    files = [p] if p.is_file() else sorted(f for f in p.iterdir() if f.suffix.lower() == ".c3d")
    clips, skipped = [], []
    for f in files:
        try:
            clips.append(read_c3d(f))
        except MocapFileError as exc:
            skipped.append((f.name, str(exc)))
    return clips, skipped


def score_markers(
    clips: Sequence[Markers],
    built: Sequence[tuple[str, Callable]],
    corpus: str,
    corruption: Corruption,
    repeats: int,
) -> tuple[list[dict], list[tuple[str, str]]]:
    """Rows of every built point method on ``repeats`` corrupted copies of each complete marker clip."""
    rows, skipped = [], []
    for truth in clips:
        for rep in range(repeats):
            rng = np.random.default_rng(seed_for(corpus, truth.name, rep, corruption))
            try:
                noisy = corrupt_markers(truth, corruption, rng)
            except ValueError as exc:
                skipped.append((truth.name, str(exc)))
                break
            missing = ~noisy.visible
            for text, clean in built:
                start = time.perf_counter()
                out = clean(noisy)
                seconds = time.perf_counter() - start
                point_err = metrics.point_err_cm(out, truth.points, missing)
                rows.append(_row(text, corruption, truth.name, rep, truth.n_frames, seconds, point_err_cm=point_err))
    return rows, skipped


def evaluate_points(
    clips: Sequence[Markers],
    corruption: str | Corruption,
    methods: Sequence[str | MethodSpec],
    repeats: int,
    corpus: str,
    progress: bool = True,
    parallel: Parallel | None = None,
) -> tuple[list[dict], list[tuple[str, str]]]:
    """Score point methods on marker clips under a ``segment-gap``/``marker-gap`` corruption.

    Markers that are not visible throughout a clip are dropped from it first so the truth is complete.
    ``parallel`` as in ``evaluate_angles``.
    """
    complete = []
    for m in clips:
        keep = np.flatnonzero(m.visible.all(axis=0))
        if keep.size:
            complete.append(m.select(keep))
    corruption = Corruption.parse(corruption)
    context = MethodContext(train=complete, corpus=corpus, corruption=corruption.text)
    specs = [MethodSpec.parse(m) for m in methods]
    built = [(str(spec), build_method(spec, context, space="points").clean) for spec in specs]
    shared = (built, corpus, corruption, repeats)
    return _scored_chunks(score_markers, complete, shared, parallel, progress, corruption)


# ---------------------------------------------------------------------------------------------- entry


def evaluate(
    data: str,
    corruption: str | Corruption,
    methods: Sequence[str | MethodSpec],
    repeats: int = 5,
    fold: int | None = None,
    limit: int | None = None,
    progress: bool = True,
    corpus: Corpus | None = None,
    style: str | None = None,
    parallel: Parallel | None = None,
) -> Evaluation:
    """Score ``methods`` on ``data`` under ``corruption`` (see module docstring).

    BVH: with ``fold`` the test clips of that fold are scored and methods may learn from its training
    folds; without it every clip is scored and trainable baselines use fold 0's training folds. The
    reference baselines needed for ratios are added when missing. ``style`` keeps only the clips of that
    style label (the unseen-style check: score a model trained with that style held out). ``parallel`` (a
    ``mocapnet.parallel.Parallel``) scores clips on Dask workers; the rows are the same as in this process
    (default) but for the ``seconds`` column.
    """
    for name, value in (("repeats", repeats), ("limit", limit)):
        if value is None:
            continue
        try:
            whole = operator.index(value) if not isinstance(value, bool) else 0
        except TypeError:
            whole = 0
        if whole < 1:
            raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
    corruption = Corruption.parse(corruption)
    specs = [MethodSpec.parse(m) for m in methods]
    asked = [str(s) for s in specs]
    if is_c3d_data(data):
        if not corruption.is_point_gap:
            raise ValueError(f"{data}: C3D data takes segment-gap:SEG:S or marker-gap:S, not {corruption.text!r}")
        clips, skipped = load_c3d_folder(data, progress)
        if limit:
            clips = clips[:limit]
        wanted = list(dict.fromkeys(asked + list(reference_methods(corruption, "points"))))
        rows, skipped2 = evaluate_points(clips, corruption, wanted, repeats, Path(str(data)).name, progress, parallel)
        return Evaluation(str(data), corruption.text, "points", wanted, rows, skipped + skipped2, None, repeats)
    corpus = corpus or load_corpus(data, progress=progress, limit=limit)
    train, _, test = corpus.split(fold if fold is not None else 0)
    clips = test if fold is not None else corpus.motions
    if style is not None:
        clips = [m for m in clips if style_label(m.name) == style]
        if not clips:
            raise ValueError(f"{corpus.name}: no clip of style {style!r} among the clips to score")
    wanted = list(dict.fromkeys(asked + corpus_references(corpus.name, corruption)))
    if not train and "gaussian-tuned" in wanted and "gaussian-tuned" not in asked:
        wanted.remove("gaussian-tuned")  # a reference that needs training clips, and there are none
        skipped = [("gaussian-tuned", "gaussian-tuned: left out of the reference, no training clips")]
    else:
        skipped = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rows, skipped2 = evaluate_angles(corpus, clips, train, corruption, wanted, repeats, progress, parallel)
    return Evaluation(
        corpus.name, corruption.text, "angles", wanted, rows, corpus.skipped + skipped + skipped2, fold, repeats
    )
