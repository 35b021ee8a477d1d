"""Tests of the data-driven gap filler (mocapnet.methods.knn) and the PCA baseline (mocapnet.methods.pca)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapnet.corpus import PACKAGE_DATA, list_bvh
from mocapnet.corrupt import corrupt_markers, corrupt_motion, motion_markers
from mocapnet.io.bvh import read_bvh, write_bvh
from mocapnet.io.c3d import read_c3d
from mocapnet.kinematics import (
    geodesic_deg,
    inverse_kinematics,
    joint_positions,
    local_rotations,
    local_translations,
    matrix_to_euler,
    rotation_sequence,
    wrap_deg,
)
from mocapnet.methods import MethodContext, build_method
from mocapnet.methods.baselines import lerp_fill
from mocapnet.methods.knn import (
    Anchors,
    MotionDatabase,
    blend_weight,
    body_frames,
    denormalise,
    derivatives,
    detect_anchors,
    downsample,
    edge_seconds,
    fill_gaps,
    fill_markers,
    normalise,
    upsample,
)
from mocapnet.methods.knn_angles import (
    ANGLE_DEFAULTS,
    fill_angles,
    fit_twists,
    limb_motion,
    limb_rms,
    own_hidden,
    pca_angles,
    pca_margin_error,
    point_parents,
    points_visible,
    short_chains,
    twist_axes,
)
from mocapnet.methods.knn_database import SkeletonDatabase, cached_database, default_corpus
from mocapnet.methods.knn_window import Searcher, WindowSettings, estimate_run
from mocapnet.methods.pca import pca_fill
from mocapnet.methods.rigid import kabsch
from mocapnet.motion import Markers, Motion

SHARED = Path(os.environ.get("MOCAPNET_DATA", Path(__file__).parents[2].parent / "shared" / "data"))
FPS = 60.0
# Shoulder / hip pivots and the distance below them of each limb marker (cm, body frame x right, y fwd, z up).
_LIMBS = {
    "L": {
        "arm": ((-18.0, 0.0, 50.0), ("LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN"), 1.0),
        "leg": ((-10.0, 0.0, 0.0), ("LTHI", "LKNE", "LSHN", "LANK", "LHEE", "LTOE"), -1.0),
    },
    "R": {
        "arm": ((18.0, 0.0, 50.0), ("RUPA", "RELB", "RFRM", "RWRA", "RWRB", "RFIN"), -1.0),
        "leg": ((10.0, 0.0, 0.0), ("RTHI", "RKNE", "RSHN", "RANK", "RHEE", "RTOE"), 1.0),
    },
}
_TRUNK = {
    "LASI": (-12, 8, 0),
    "RASI": (12, 8, 0),
    "LPSI": (-6, -9, 2),
    "RPSI": (6, -9, 2),
    "C7": (0, -5, 55),
    "STRN": (0, 10, 35),
    "LFHD": (-6, 8, 72),
    "RFHD": (6, 8, 72),
    "LBHD": (-6, -6, 70),
    "RBHD": (6, -6, 70),
    "LSHO": (-17, 0, 53),
    "RSHO": (17, 0, 53),
}


def synthetic_walk(
    n_frames: int = 300, phase: float = 0.0, stride_hz: float = 1.0, swing: float = 0.5, name: str = "walk"
) -> Markers:
    """A Plug-in-Gait-labelled stick figure walking on a curve, limbs swinging ``±swing`` rad, ``[T, 34, 3]`` cm."""
    t = np.arange(n_frames) / FPS
    labels: list[str] = list(_TRUNK)
    local = [np.broadcast_to(np.array(v, dtype=float), (n_frames, 3)) for v in _TRUNK.values()]
    for sides in _LIMBS.values():
        for pivot, names, sign in sides.values():
            angle = swing * sign * np.sin(2 * np.pi * stride_hz * t + phase)
            # A sideways cosine sway too, so that a pose fixes the phase (no pose recurs with another velocity).
            sway = 4.0 * np.cos(2 * np.pi * stride_hz * t + phase)
            for r, lab in zip(np.linspace(8.0, 45.0, len(names)), names):
                offset = np.stack([sway * r / 45.0, r * np.sin(angle), -r * np.cos(angle)], axis=1)
                local.append(np.array(pivot) + offset)
                labels.append(lab)
    pts = np.stack(local, axis=1)
    heading = 0.4 * np.sin(0.3 * t + phase)
    rot = np.zeros((n_frames, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1] = np.cos(heading), -np.sin(heading)
    rot[:, 1, 0], rot[:, 1, 1] = np.sin(heading), np.cos(heading)
    rot[:, 2, 2] = 1.0
    root = np.stack([40.0 * t, 15.0 * np.sin(0.5 * t), 95.0 + 2.0 * np.sin(4 * np.pi * stride_hz * t)], axis=1)
    world = np.einsum("tij,tmj->tmi", rot, pts) + root[:, None]
    return Markers(world, np.ones(world.shape[:2], dtype=bool), labels, FPS, name)


@pytest.fixture(scope="module")
def walk() -> Markers:
    return synthetic_walk()


@pytest.fixture(scope="module")
def database(walk: Markers) -> MotionDatabase:
    """Contains the test motion (under another name) and two with other poses (smaller / larger swing)."""
    copy = Markers(walk.points, walk.visible, walk.labels, FPS, "database copy")
    others = [
        synthetic_walk(phase=1.0, stride_hz=1.3, swing=0.3, name="small"),
        synthetic_walk(phase=2.0, swing=0.7, name="large"),
    ]
    return MotionDatabase.from_markers([copy, *others])


@pytest.mark.parametrize("corruption", ["segment-gap:left-arm:1", "segment-gap:legs:2", "marker-gap:1.5"])
def test_exact_when_the_database_contains_the_motion(walk, database, corruption: str) -> None:
    noisy = corrupt_markers(walk, corruption, np.random.default_rng(3))
    out, report = fill_gaps(noisy, database, k=4)
    miss = ~noisy.visible
    assert report.gaps == 1 and not report.unfilled
    assert np.linalg.norm(out - walk.points, axis=-1)[miss].max() < 1e-3


def test_nearby_gaps_of_one_marker(walk, database) -> None:
    """Several short gaps close together (another gap inside a gap's context window), as in real data."""
    visible = walk.visible.copy()
    lwra = walk.labels.index("LWRA")
    for start in (100, 112, 125, 140):
        visible[start : start + 6, lwra] = False
    visible[150:154, walk.labels.index("RKNE")] = False
    noisy = Markers(walk.points, visible, walk.labels, FPS, "walk")
    out, report = fill_gaps(noisy, database)
    assert report.gaps == 5 and np.isfinite(out).all()
    assert np.linalg.norm(out - walk.points, axis=-1)[~visible].max() < 1e-3


def test_visible_points_never_change(walk) -> None:
    other = MotionDatabase.from_markers([synthetic_walk(phase=1.0, stride_hz=1.3, swing=0.3, name="small")])
    noisy = corrupt_markers(walk, "segment-gap:arms:1.5", np.random.default_rng(0))
    out, _ = fill_gaps(noisy, other)
    assert np.array_equal(out[noisy.visible], noisy.points[noisy.visible])
    assert np.isfinite(out).all()
    assert not np.allclose(out[~noisy.visible], walk.points[~noisy.visible], atol=1e-3)  # a real estimate


def test_body_frame_round_trip_and_heading(walk) -> None:
    anchors = detect_anchors(walk.labels)
    assert anchors.left == ("LASI", "LPSI") and anchors.right == ("RASI", "RPSI")
    origin, rot = body_frames(walk.points, walk.visible, walk.labels, anchors, up=2)
    local = normalise(walk.points, origin, rot)
    assert np.allclose(denormalise(local, origin, rot), walk.points)
    # The body shape is constant in the body frame; left hip on the left (x < 0), up is z.
    assert not np.allclose(local, local[0], atol=1e-9)  # limbs swing
    lasi = walk.labels.index("LASI")
    assert np.allclose(local[:, lasi], local[0, lasi]) and local[0, lasi, 0] < 0
    assert np.allclose(np.einsum("tij,tik->tjk", rot, rot), np.eye(3))


def test_missing_pelvis_follows_the_shoulders(walk) -> None:
    """With the pelvis markers gone for 1.5 s of a turning walk, the frames come from the shoulders."""
    anchors = detect_anchors(walk.labels)
    full = body_frames(walk.points, walk.visible, walk.labels, anchors, up=2)
    visible = walk.visible.copy()
    visible[100:190, [walk.labels.index(m) for m in ("LASI", "RASI", "LPSI", "RPSI")]] = False
    gappy = body_frames(walk.points, visible, walk.labels, anchors, up=2)
    assert np.allclose(gappy[0], full[0], atol=1e-9) and np.allclose(gappy[1], full[1], atol=1e-9)
    no_backup = Anchors(anchors.origin, anchors.left, anchors.right)
    interpolated = body_frames(walk.points, visible, walk.labels, no_backup, up=2)
    assert np.abs(interpolated[0] - full[0]).max() > 1.0  # plain interpolation misses the curve


def test_skeleton_anchors() -> None:
    cmu = detect_anchors(["Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "RHipJoint", "RightUpLeg", "Spine"])
    assert (cmu.origin, cmu.left, cmu.right) == (("HIPS", "LEFTUPLEG", "RIGHTUPLEG"), ("LEFTUPLEG",), ("RIGHTUPLEG",))
    bandai = detect_anchors(["joint_Root", "Hips", "Spine", "UpperLeg_L", "LowerLeg_L", "UpperLeg_R"])
    assert bandai.left == ("UPPERLEG_L",) and bandai.right == ("UPPERLEG_R",) and bandai.backup() is None
    with_shoulders = detect_anchors(["Hips", "UpperLeg_L", "UpperLeg_R", "Shoulder_L", "Shoulder_R"])
    assert (with_shoulders.backup_left, with_shoulders.backup_right) == (("SHOULDER_L",), ("SHOULDER_R",))
    assert detect_anchors(["a", "b", "c"]).kind == "centroid"


def test_multi_resolution_round_trip(database) -> None:
    rng = np.random.default_rng(1)
    for level in (1, 2, 3):
        coarse = rng.normal(size=(12, 4, 3))
        n = (len(coarse) - 1) * 2**level + 1
        assert np.array_equal(downsample(upsample(coarse, n, level), level), coarse)
        line = np.linspace(0, 10, n)[:, None, None] * np.array([1.0, -2.0, 0.5])
        assert np.allclose(upsample(downsample(line, level), n, level), line)
    quad = (np.arange(20.0) * 0.1) ** 2  # x = t², dt = 0.1 s: velocity 2t, acceleration 2
    vel, acc = derivatives(quad, 0.1)
    assert np.allclose(vel[1:-1], 2 * np.arange(20.0)[1:-1] * 0.1) and np.allclose(acc[1:-1], 2.0)
    # Levels halve the rate; together they stay under twice the full-rate store.
    lengths = [len(level.clip) for level in database.levels]
    assert lengths == [sum(-(-300 // 2**i) for _ in range(3)) for i in range(len(lengths))]
    assert database.nbytes < 2 * database.levels[0].nbytes


def test_error_names_file_and_database_when_marker_sets_differ(walk) -> None:
    renamed = Markers(walk.points, walk.visible, [f"M{i}" for i in range(walk.n_markers)], FPS, "other set")
    db = MotionDatabase.from_markers([renamed], source="folder/of/other-set")
    noisy = corrupt_markers(walk, "segment-gap:left-arm:1", np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"walk: database folder/of/other-set .* does not contain marker\(s\)"):
        fill_gaps(noisy, db)


def test_gaps_over_max_length_left_nan_or_interpolated_with_warning(walk, database) -> None:
    noisy = corrupt_markers(walk, "segment-gap:left-arm:1", np.random.default_rng(0))
    out, report = fill_gaps(noisy, database, max_gap_s=0.5)
    assert np.isnan(out[~noisy.visible]).all()
    assert {u[0] for u in report.unfilled} == {"LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN"}
    other = synthetic_walk(phase=1.0, swing=0.3, name="other")
    method = build_method("knn:search=energy,max_gap_s=0.5", MethodContext(train=[other]), space="points")
    with pytest.warns(UserWarning) as caught:
        filled = method.clean(noisy)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 6 and all("walk: knn left a gap unfilled" in m for m in messages)
    assert any(re.search(r"marker LUPA frames \d+-\d+ filled by linear interpolation", m) for m in messages)
    assert np.isfinite(filled).all()


def test_registered_methods_build_and_run(walk) -> None:
    noisy = corrupt_markers(walk, "segment-gap:right-arm:1", np.random.default_rng(2))
    same_name = Markers(walk.points, walk.visible, walk.labels, FPS, "walk")
    train = [same_name, synthetic_walk(phase=2.0, swing=0.7, name="x")]
    knn = build_method("knn:k=4", MethodContext(train=train), space="points")
    pca = build_method("pca")
    assert knn.space == pca.space == "points" and knn.options == {"k": 4}
    assert build_method("knn").space == "angles"  # BVH data: the joint-space kNN (knn_angles)
    for method in (knn, pca):
        out = method.clean(noisy)
        assert out.shape == walk.points.shape and np.isfinite(out).all()
        assert np.array_equal(out[noisy.visible], walk.points[noisy.visible])
    # The clip named like the input is left out of the database: the fill is not a copy of the truth...
    alone = build_method("knn:k=4,own=False", MethodContext(train=train), space="points")
    err = np.linalg.norm(alone.clean(noisy) - walk.points, axis=-1)[~noisy.visible].mean()
    assert 1e-3 < err < 20.0
    # ...but the take's own observed frames are fair game: this walk repeats exactly every second.
    err = np.linalg.norm(knn.clean(noisy) - walk.points, axis=-1)[~noisy.visible].mean()
    assert err < 1e-6 and "own frames" in knn.clean.database


def test_knn_on_joint_positions_of_a_motion() -> None:
    """BVH corpora: the database may be given as motions (their joint positions are used)."""
    motion = read_bvh(PACKAGE_DATA / "bvh" / "01_01.bvh.gz")
    half = motion.n_frames // 2
    train, test = motion.with_channels(motion.channels[:half]), motion.with_channels(motion.channels[half:])
    truth = motion_markers(test)
    arm = [i for i, n in enumerate(truth.labels) if n in ("LeftForeArm", "LeftHand")]
    visible = truth.visible.copy()
    visible[200:320, arm] = False
    noisy = Markers(truth.points, visible, truth.labels, truth.fps, "second half")
    out = build_method("knn", MethodContext(train=[train]), space="points").clean(noisy)
    err = np.linalg.norm(out - truth.points, axis=-1)[~visible].mean()
    assert np.isfinite(out).all() and err < 15.0


def test_pca_fills_a_real_gap_better_than_nothing() -> None:
    tennis = read_c3d(PACKAGE_DATA / "c3d" / "kinematics_tennis_serve.c3d")
    for corruption, bound in (("marker-gap:1", 5.0), ("segment-gap:right-leg:2", None)):
        noisy = corrupt_markers(tennis, corruption, np.random.default_rng(0))
        miss = ~noisy.visible
        out = pca_fill(noisy.points, noisy.visible)
        err = np.linalg.norm(out - tennis.points, axis=-1)[miss].mean()
        nothing = np.linalg.norm(np.nanmean(noisy.points, axis=0) - tennis.points, axis=-1)[miss].mean()
        assert np.isfinite(out).all() and np.array_equal(out[~miss], tennis.points[~miss])
        assert err < 0.7 * nothing and (bound is None or err < bound)


def test_database_folder_option_leaves_the_file_out() -> None:
    folder = SHARED / "c3d" / "cmu"
    if not folder.is_dir():
        pytest.skip(f"shared data not found at {SHARED}")
    clip = read_c3d(folder / "85_02.c3d")
    noisy = corrupt_markers(clip, "segment-gap:left-arm:1", np.random.default_rng(0))
    out = build_method(f"knn:database={folder},k=4", space="points").clean(noisy)
    err = np.linalg.norm(out - clip.points, axis=-1)[~noisy.visible].mean()
    assert np.array_equal(out[noisy.visible], clip.points[noisy.visible])
    assert 0.1 < err < 100.0  # the file itself (in the folder) was not used


# ------------------------------------------------------------------------------------------ joint space


def _cmu_parts() -> tuple[Motion, Motion, Motion]:
    """Three 400-frame pieces of the shipped CMU clip (120 fps)."""
    motion = read_bvh(PACKAGE_DATA / "bvh" / "01_01.bvh.gz")
    return tuple(Motion(motion.skeleton, motion.channels[a : a + 400], motion.fps, f"part{a}") for a in (0, 900, 1800))  # type: ignore[return-value]


@pytest.fixture(scope="module")
def parts() -> tuple[Motion, Motion, Motion]:
    return _cmu_parts()


def _segment_gap(motion: Motion, corruption: str, seed: int = 0) -> tuple[Motion, np.ndarray]:
    noisy, mask = corrupt_motion(motion, corruption, np.random.default_rng(seed))
    return motion.with_channels(noisy), mask


def _gap_rms(out: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(wrap_deg(out[mask] - truth[mask]) ** 2)))


@pytest.mark.parametrize("corruption", ["segment-gap:left-arm:1", "segment-gap:legs:1"])
def test_angles_exact_when_the_database_holds_the_truth(parts, corruption: str) -> None:
    """The kNN must copy the truth from the database (lerp, or anything that ignores it, cannot)."""
    truth = parts[1]
    db = SkeletonDatabase.from_motions([parts[0], truth.with_channels(truth.channels), parts[2]])
    db.names = ("part0", "copy of the truth", "part1800")  # the copy is not left out as "the same clip"
    noisy, mask = _segment_gap(truth, corruption)
    out, stats = fill_angles(noisy, mask, db)
    assert stats.gaps == 1
    assert _gap_rms(out, truth.channels, mask) < 1e-3
    assert _gap_rms(lerp_fill(noisy.channels, mask), truth.channels, mask) > 1.0


def test_angles_blend_never_moves_observed_samples_and_uses_the_database(parts) -> None:
    truth = parts[1]
    db = SkeletonDatabase.from_motions([parts[0], parts[2]])
    noisy, mask = _segment_gap(truth, "segment-gap:right-arm:1", seed=4)
    out, _ = fill_angles(noisy, mask, db)
    assert np.array_equal(out[~mask], truth.channels[~mask]) and np.isfinite(out).all()
    lerp = lerp_fill(noisy.channels, mask)
    assert np.abs(out[mask] - lerp[mask]).max() > 1.0  # not interpolation in disguise
    # The clip itself is never its own neighbour: a database of the clip alone has nothing to offer.
    alone = SkeletonDatabase.from_motions([truth])
    with pytest.raises(ValueError, match="no clip of .* frames left to search"):
        fill_angles(noisy, mask, alone)


def test_blend_weight_and_edge_seconds() -> None:
    missing = np.array([0, 1, 1, 1, 1, 0], dtype=bool)[:, None]
    assert np.array_equal(edge_seconds(missing, 2.0).ravel(), [0, 0.5, 1.0, 1.0, 0.5, 0])
    beta = blend_weight(np.array([0.0, 1.0, 1.0, 5.0]), np.array([0.1, 0.1, 1.0, 1.0]), 10.0)
    assert beta[0] == 1.0 and beta[1] == 0.5 and beta[2] > beta[3] > beta[1]  # agree: 1; spread or edge: less


def test_points_blend_keeps_observed_samples_and_the_take_is_its_own_database() -> None:
    tennis = read_c3d(PACKAGE_DATA / "c3d" / "kinematics_tennis_serve.c3d")
    noisy = corrupt_markers(tennis, "marker-gap:0.5", np.random.default_rng(1))
    knn = build_method("knn", MethodContext(), space="points")
    out = knn.clean(noisy)
    assert "own frames" in knn.clean.database
    assert np.array_equal(out[noisy.visible], tennis.points[noisy.visible]) and np.isfinite(out).all()
    lerp = build_method("lerp", space="points").clean(noisy)
    assert np.abs(out - lerp)[~noisy.visible].max() > 0.01


def test_database_cache_is_npz_and_a_tampered_entry_is_rebuilt(parts, tmp_path, monkeypatch) -> None:
    folder = tmp_path / "corpus"
    for m in parts:
        write_bvh(folder / f"{m.name}.bvh", m)
    monkeypatch.setenv("MOCAPNET_CACHE", str(tmp_path / "cache"))
    db = cached_database(str(folder))
    (entry,) = (tmp_path / "cache").glob("knn-*.npz")
    assert entry.read_bytes()[:2] == b"PK"  # a zip of .npy arrays, not a pickle
    with np.load(entry, allow_pickle=False) as npz:  # every array loads without pickle
        arrays = {k: npz[k] for k in npz.files}
    assert len(db.names) == 3 and db.points.shape == (1200, len(db.labels), 3)
    again = cached_database(str(folder))
    assert np.array_equal(again.channels, db.channels) and again.names == db.names
    arrays["channels"] = arrays["channels"] + 1.0  # tampered: the stored checksum no longer matches
    np.savez(entry, **arrays)
    with pytest.warns(UserWarning, match="checksum mismatch"):
        rebuilt = cached_database(str(folder))
    assert np.array_equal(rebuilt.channels, db.channels)
    SkeletonDatabase.load(entry)  # rewritten with a valid checksum


def test_registered_knn_fills_bvh_in_joint_space(parts, tmp_path) -> None:
    folder = tmp_path / "db"
    for m in (parts[0], parts[2]):
        write_bvh(folder / f"{m.name}.bvh", m)
    method = build_method(f"knn:database={folder}", MethodContext())
    truth = parts[1]
    noisy, mask = _segment_gap(truth, "segment-gap:left-leg:1", seed=2)
    out = method.clean(noisy, mask)
    assert method.space == "angles" and str(folder.name) in method.clean.database
    assert np.array_equal(out[~mask], truth.channels[~mask]) and np.isfinite(out).all()


def test_default_database_is_the_largest_corpus_of_the_skeleton(shared) -> None:
    bandai = read_bvh(list_bvh(shared / "bvh" / "bandai_namco_1")[0])
    assert default_corpus(bandai.skeleton) == "bandai2"


def test_window_search_on_points_is_exact_with_the_truth_in_the_database(walk, database) -> None:
    noisy = corrupt_markers(walk, "segment-gap:left-arm:1", np.random.default_rng(3))
    out, stats = fill_markers(noisy, database, WindowSettings(own=False))
    assert stats.gaps == 1 and np.array_equal(out[noisy.visible], walk.points[noisy.visible])
    assert np.linalg.norm(out - walk.points, axis=-1)[~noisy.visible].max() < 1e-3
    method = build_method(
        "knn:search=window", MethodContext(train=[synthetic_walk(phase=1.0, name="o")]), space="points"
    )
    assert np.isfinite(method.clean(noisy)).all()


def test_searcher_shares_the_database_points_and_builds_one_coarse_table(parts) -> None:
    """Memory: a clean float32 database is searched in place; only the table of the step used is added."""
    db = SkeletonDatabase.from_motions([parts[0], parts[2]])
    searcher = Searcher(db.points, db.clip, db.describe())
    assert np.shares_memory(searcher.points, db.points)
    noisy, mask = _segment_gap(parts[1], "segment-gap:left-arm:1")
    fill_angles(noisy, mask, db, searcher=searcher)
    assert list(searcher._tables) == [3] and searcher.table(3).shape == (4 * len(db.labels), -(-len(db.clip) // 3))


def test_max_weight_caps_the_knn_share_and_bad_settings_are_refused() -> None:
    """``max_weight`` 0.5 gives the mean of the kNN estimate and the fallback where the neighbours agree."""
    n = 20
    near = np.linspace(0.0, 10.0, n)[:, None] + np.stack([np.sin(np.arange(n)), np.cos(np.arange(n))], 1) * 4.0
    kernel = np.array([0.5, 0.5])
    seconds = np.full(n, 1e3)  # far from the observed frames: the blend weight is max_weight
    base, anchor = np.linspace(0.0, 10.0, n), np.full(n, -3.0)

    def blend(settings: WindowSettings) -> np.ndarray:
        t, est, beta = estimate_run(base, near, kernel, seconds, 0, (5, 15), 0.0, settings)
        assert np.array_equal(t, np.arange(5, 15))  # only the run is estimated
        return anchor[t] + beta * (est - anchor[t])

    full, half = blend(WindowSettings(speed=60.0)), blend(WindowSettings(speed=60.0, max_weight=0.5))
    assert np.allclose(half, 0.5 * (full + anchor[5:15])) and np.abs(full - anchor[5:15]).max() > 1.0
    capped = blend(WindowSettings(speed=1.0, plateau_s=0.01))  # the fallback's error stops growing 0.01 s out
    assert np.abs(capped - anchor[5:15]).max() < np.abs(full - anchor[5:15]).max()  # the kNN share shrinks
    bad_settings = (
        {"max_weight": 1.5},
        {"k": 0},
        {"fallback": "spline"},
        {"plateau_s": 0.0},
        {"limb_gate": -1.0},
        {"twist": "x"},
        {"short_chain": 0.0},
        {"pca_gate": 0.0},
        {"fit_twist": -0.5},
    )
    for bad in bad_settings:
        with pytest.raises(ValueError, match="knn: k must be"):
            WindowSettings(**bad)
    flags = ({"gated_twist": "false"}, {"offset": 1}, {"short_chain": "none"}, {"pca_gate": True}, {"pca_pair": "1"})
    for bad in (*flags, {"fit_twist": "0"}):
        with pytest.raises(ValueError, match="knn: .* must be"):  # a misspelt flag or gate is not taken as set
            WindowSettings(**bad)


def test_kabsch_per_pair_recovers_a_rotation_and_cluster_fill_stays_exact(walk, database) -> None:
    rng = np.random.default_rng(5)
    src = rng.normal(size=(2, 5, 3)) * 10.0
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))  # a proper rotation
    dst = src @ rot.T + np.array([1.0, -2.0, 3.0])
    got_rot, got_shift = kabsch(src, dst)
    assert np.allclose(got_rot, rot) and np.allclose(got_shift, [1.0, -2.0, 3.0])
    noisy = corrupt_markers(walk, "segment-gap:left-arm:1", np.random.default_rng(3))
    out, _ = fill_gaps(noisy, database, k=4, cluster=4)
    assert np.array_equal(out[noisy.visible], walk.points[noisy.visible])
    assert np.linalg.norm(out - walk.points, axis=-1)[~noisy.visible].max() < 1e-2


def test_limb_distance_measures_the_missing_points_where_they_are_observed() -> None:
    rng = np.random.default_rng(2)
    feats = rng.normal(size=(10, 3, 3))
    stored = feats.copy()
    stored[:, 2] += [2.0, 0.0, 0.0]  # the neighbour is 2 cm off on the missing point only
    stored[:, 0] += 50.0  # and far off on an observed one, which limb_rms ignores
    w = np.ones((10, 3))
    w[4:6, 2] = 0.0  # point 2 missing in the gap [4, 6)
    args = (np.array([0]), np.array([False]), np.arange(10), 0)
    assert np.isclose(limb_rms(stored, feats, *args, w, np.array([1.0]), (4, 6)), 2.0)
    w[:, 2] = 0.0  # never observed in the window: no limb distance
    assert np.isnan(limb_rms(stored, feats, *args, w, np.array([1.0]), (4, 6)))


# The defaults without the fallback options of rounds E and H (knn_tuning_fallback.md, knn_tuning_pair.md), so that
# the tests below see each option alone.
_PLAIN = {**ANGLE_DEFAULTS, "twist": "lerp", "gated_twist": False, "short_chain": None, "still_gate": None,
          "pca_pair": False, "fit_twist": None, "pca_gate": None}  # fmt: skip


def _fallback(noisy: Motion, mask: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """The PCA fallback of ``fill_angles`` with its IK's twist taken from ``twist [T, C]``."""
    sk = noisy.skeleton
    joint_missing = np.stack([mask[:, sk.joint_channels(j)].any(axis=1) for j in range(sk.n_joints)], axis=1)
    return pca_angles(noisy, mask, twist, points_visible(sk, joint_missing))


def test_limb_gates_fall_back_to_pca_and_keep_the_truth(parts) -> None:
    """A gate below every neighbour's limb distance gives the PCA fallback itself; with the truth in the
    database the limb distance is 0, nothing is gated and the fill stays exact, twist option on or off."""
    truth = parts[1]
    noisy, mask = _segment_gap(truth, "segment-gap:left-arm:1", seed=4)
    other = SkeletonDatabase.from_motions([parts[0], parts[2]])
    scored = mask & truth.skeleton.scored_mask[None]
    fallback = _fallback(noisy, mask, lerp_fill(noisy.channels, mask))
    ungated, _ = fill_angles(noisy, mask, other, WindowSettings(**_PLAIN))
    assert np.abs(wrap_deg(ungated - fallback))[scored].max() > 1.0  # a gate that did nothing would fail below
    for gate in ({"limb_gate": 1e-6}, {"still_gate": 1e-9}, {"pca_gate": 1e-9}):
        gated, stats = fill_angles(noisy, mask, other, WindowSettings(**{**_PLAIN, **gate}))
        assert min(stats.limb_distance) > 1e-6
        assert np.allclose(gated[scored], fallback[scored], atol=1e-9)
        assert np.array_equal(gated[~mask], noisy.channels[~mask])
    wide, _ = fill_angles(noisy, mask, other, WindowSettings(**{**_PLAIN, "pca_gate": 1e9}))
    assert np.array_equal(wide, ungated)  # a gate above every ratio changes nothing
    db = SkeletonDatabase.from_motions([parts[0], truth.with_channels(truth.channels), parts[2]])
    db.names = ("part0", "copy of the truth", "part1800")
    for twist in ("lerp", "knn", "blend"):
        for gated_twist in (False, True):
            gates = {"limb_gate": 1.0, "still_gate": 1.0, "pca_gate": 1.0, "twist": twist, "gated_twist": gated_twist}
            out, _ = fill_angles(noisy, mask, db, WindowSettings(**{**ANGLE_DEFAULTS, **gates}))
            assert _gap_rms(out, truth.channels, mask) < 1e-3


def test_twist_from_knn_changes_the_fallback_angles_not_its_positions(parts) -> None:
    """With the blend all fallback (speed ~0), ``twist="knn"`` gives the PCA fallback whose IK takes its twist
    from the kNN estimate: other angles than with the twist of interpolation, the same joint positions."""
    truth = parts[1]
    noisy, mask = _segment_gap(truth, "segment-gap:left-arm:1", seed=4)
    db = SkeletonDatabase.from_motions([parts[0], parts[2]])
    knn_only, _ = fill_angles(noisy, mask, db, WindowSettings(**{**_PLAIN, "speed": None}))
    settings = {**_PLAIN, "speed": 1e-9}
    plain, _ = fill_angles(noisy, mask, db, WindowSettings(**settings))
    twisted, _ = fill_angles(noisy, mask, db, WindowSettings(**{**settings, "twist": "knn"}))
    scored = mask & truth.skeleton.scored_mask[None]
    assert np.allclose(twisted[scored], _fallback(noisy, mask, knn_only)[scored], atol=1e-6)
    assert np.abs(wrap_deg(twisted - plain))[scored].max() > 1.0  # the twist differs
    pos = [joint_positions(noisy.with_channels(c), end_sites=True) for c in (plain, twisted)]
    assert np.abs(pos[0] - pos[1]).max() < 1e-6


def test_limb_motion_is_the_limbs_own_rms_about_its_mean_where_observed() -> None:
    feats = np.zeros((10, 3, 3))
    feats[:, 2, 0] = np.where(np.arange(10) % 2 == 0, 2.0, -2.0)  # point 2 swings ±2 cm about 0
    feats[:, 0] = 50.0 * np.arange(10)[:, None]  # an observed point moving a lot: not the limb
    w = np.ones((10, 3))
    w[4:6, 2] = 0.0  # point 2 missing in the gap [4, 6)
    assert np.isclose(limb_motion(feats, np.arange(10), w, (4, 6)), 2.0)
    w[:, 2] = 0.0
    assert np.isnan(limb_motion(feats, np.arange(10), w, (4, 6)))


def test_pca_margin_error_is_pcas_own_error_at_rebuilding_the_limb_where_it_is_observed() -> None:
    """A limb point that moves with the rest of the body (rank-one motion, amplitude ~10 cm) is rebuilt in the
    margins to within 0.1 cm (Federolf's ``M V0 T V1ᵀ`` is close, not exact); one that moves on its own is not
    (about its own RMS motion); a limb never observed in the window gives NaN."""
    t = np.arange(200)
    rng = np.random.default_rng(5)
    pos = rng.normal(scale=20.0, size=(1, 6, 3)) + rng.normal(size=(1, 6, 3)) * 10.0 * np.sin(t / 9.0)[:, None, None]
    visible = np.ones((200, 6), dtype=bool)
    visible[90:110, 5] = False  # point 5 (the limb) missing in the gap [90, 110)
    grid = np.arange(70, 130, 2)
    w = visible[grid].astype(float)
    assert pca_margin_error(pos, visible, grid, w, (90, 110)) < 0.1
    own = pos.copy()
    own[:, 5] += rng.normal(scale=3.0, size=(200, 3))  # the limb's own motion, unrelated to the others
    err = pca_margin_error(own, visible, grid, w, (90, 110))
    assert 3.0 < err < 10.0  # about sqrt(3) * 3 cm
    visible[:, 5] = False
    assert np.isnan(pca_margin_error(pos, visible, grid, np.zeros_like(w), (90, 110)))


def _gated_arm_case(parts):
    """A left-arm:1 gap in ``parts[1]`` and a database holding the truth with the left arm's angles offset by
    0.5° (the limb distance is above a tiny gate; the offset-corrected estimate is nearly the truth):
    ``(noisy, mask, database, the pure kNN estimate)``."""
    truth = parts[1]
    noisy, mask = _segment_gap(truth, "segment-gap:left-arm:1", seed=4)
    shifted = truth.channels.copy()
    shifted[:, np.flatnonzero(mask.any(axis=0))] += 0.5
    db = SkeletonDatabase.from_motions([parts[0], truth.with_channels(shifted), parts[2]])
    db.names = ("part0", "the truth, offset", "part1800")
    knn_only, _ = fill_angles(noisy, mask, db, WindowSettings(**{**_PLAIN, "speed": None}))
    return noisy, mask, db, knn_only


def test_gated_twist_keeps_the_pca_positions_and_takes_the_better_angles(parts) -> None:
    """A gated gap with ``gated_twist`` is the PCA fallback whose IK takes its twist and the angles positions do
    not set from the kNN estimate: the same joint and End Site positions as the gate's plain fallback (which
    takes them from interpolation), other angles, and closer to the truth on the joints whose rotation the IK
    takes whole from its reference; observed samples stay as they were. The database holds the truth with the
    left arm's angles offset by 0.5°: the limb distance is above the gate, and the offset-corrected estimate
    is nearly the truth."""
    truth = parts[1]
    sk = truth.skeleton
    noisy, mask, db, knn_only = _gated_arm_case(parts)
    gate = {**_PLAIN, "limb_gate": 1e-6, "twist": "knn"}
    plain, stats = fill_angles(noisy, mask, db, WindowSettings(**gate))
    kept, _ = fill_angles(noisy, mask, db, WindowSettings(**{**gate, "gated_twist": True}))
    assert min(stats.limb_distance) > 1e-6  # the gap is gated
    scored = mask & sk.scored_mask[None]
    lerp = lerp_fill(noisy.channels, mask)
    assert np.allclose(plain[scored], _fallback(noisy, mask, lerp)[scored], atol=1e-9)
    assert np.allclose(kept[scored], _fallback(noisy, mask, knn_only)[scored], atol=1e-6)
    assert np.array_equal(kept[~mask], noisy.channels[~mask])
    assert np.abs(wrap_deg(kept - plain))[scored].max() > 1.0  # the option changes the angles
    pos = [joint_positions(noisy.with_channels(c), end_sites=True) for c in (plain, kept)]
    assert np.abs(pos[0] - pos[1]).max() < 1e-6  # cm: the positions stay PCA's
    rows = mask.any(axis=1)
    rot = {k: local_rotations(sk, c)[rows] for k, c in (("truth", truth.channels), ("lerp", lerp), ("plain", plain),
                                                          ("kept", kept))}  # fmt: skip
    whole = [j for j in sk.scored_joints if mask[:, sk.joint_channels(j)].any()
             and geodesic_deg(rot["plain"][:, j], rot["lerp"][:, j]).max() < 1e-6]  # fmt: skip
    assert whole  # the IK takes some joint whole from its reference
    for j in whole:
        err = {k: geodesic_deg(rot[k][:, j], rot["truth"][:, j]).mean() for k in ("plain", "kept")}
        assert err["kept"] < 0.5 * err["plain"], (sk.names[j], err)


def test_short_chains_take_the_reference_angles_and_leave_the_other_positions(parts) -> None:
    """``short_chain``: in the PCA fallback, joints whose subtree lies within that many cm (CMU at 15 cm: the
    hands and fingers, the toes) keep their reference's angles, here the nearly true kNN estimate of a gated
    gap (``gated_twist``); every other joint and End Site stays where the plain fallback puts it. Without it
    the fingers' angles come from PCA's positions a few cm apart, far off; with it the gap is much closer to
    the truth."""
    truth = parts[1]
    sk = truth.skeleton
    chains = short_chains(sk, 15.0)
    kept_joints = {sk.names[j] for j in range(sk.n_joints) if chains[sk.joint_channels(j)].all()}
    assert {"LeftHand", "LFingers", "LThumb", "LeftToeBase"} <= kept_joints and "LeftForeArm" not in kept_joints
    for j in range(1, sk.n_joints):  # whole subtrees: a kept joint's children are kept
        assert not chains[sk.joint_channels(sk.parents[j])].any() or chains[sk.joint_channels(j)].all()
    noisy, mask, db, knn_only = _gated_arm_case(parts)
    gate = {**_PLAIN, "limb_gate": 1e-6, "twist": "knn", "gated_twist": True}
    plain, _ = fill_angles(noisy, mask, db, WindowSettings(**gate))
    short, _ = fill_angles(noisy, mask, db, WindowSettings(**{**gate, "short_chain": 15.0}))
    in_chain = mask & chains[None]
    assert in_chain.any() and np.array_equal(short[in_chain], knn_only[in_chain])
    assert np.array_equal(short[mask & ~chains[None]], plain[mask & ~chains[None]])
    assert np.array_equal(short[~mask], noisy.channels[~mask])
    pos = [joint_positions(noisy.with_channels(c), end_sites=True) for c in (plain, short)]
    still = [i for i, p in enumerate(point_parents(sk)) if p < 0 or not chains[sk.joint_channels(p)].any()]
    assert np.abs(pos[0][:, still] - pos[1][:, still]).max() < 1e-6  # only points hanging from kept joints move
    assert _gap_rms(short, truth.channels, mask) < 0.75 * _gap_rms(plain, truth.channels, mask)


def _turn_about_bone(motion: Motion, joint: int, child: int, theta: np.ndarray) -> np.ndarray:
    """Channels of ``motion`` with ``joint`` turned by ``theta [T]`` (rad) about its bone to ``child`` and
    ``child`` turned back: every point stays where it was."""
    sk = motion.skeleton
    rot = local_rotations(sk, motion.channels)
    axis = local_translations(sk, motion.channels)[:, child]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    turn = Rotation.from_rotvec(theta[:, None] * axis).as_matrix()
    out = motion.channels.copy()
    for j, r in ((joint, rot[:, joint] @ turn), (child, np.swapaxes(turn, 1, 2) @ rot[:, child])):
        seq, cols = rotation_sequence(sk, j)
        out[:, cols] = matrix_to_euler(r, seq, reference=motion.channels[:, cols])
    return out


def test_fit_twists_turns_the_bone_back_to_the_references_bend_and_moves_no_point(parts) -> None:
    """``fit_twists`` only turns a joint with one bone about it (child turned back): no point moves. The upper
    arm of the truth turned by up to 60° about its bone (the elbow's local rotation turned back) is found again
    from the truth as the reference, with or without the joint's own term; with another reference, θ is the
    best of a fine grid of turns; channels outside ``change`` are never touched."""
    truth = parts[1]
    sk = truth.skeleton
    arm, fore = sk.names.index("LeftArm"), sk.names.index("LeftForeArm")
    assert (arm, fore) in twist_axes(sk, truth.channels)
    assert sk.names.index("LeftHand") not in {j for j, _ in twist_axes(sk, truth.channels)}  # several fingers
    turned = _turn_about_bone(truth, arm, fore, np.radians(60.0) * np.sin(np.arange(truth.n_frames) / 20.0))
    pos = joint_positions(truth, end_sites=True)
    assert np.abs(joint_positions(truth, turned, end_sites=True) - pos).max() < 1e-6  # cm
    assert np.abs(wrap_deg(turned - truth.channels)).max() > 30.0
    change = np.zeros(truth.channels.shape, dtype=bool)
    change[100:300, np.concatenate([rotation_sequence(sk, j)[1] for j in (arm, fore)])] = True
    for own in (0.0, 1.0):
        out = fit_twists(sk, turned, truth.channels, change, own)
        assert np.abs(wrap_deg(out - truth.channels))[change].max() < 1e-6
        assert np.array_equal(out[~change], turned[~change])
        assert np.abs(joint_positions(truth, out, end_sites=True) - pos).max() < 1e-6
    other = truth.channels + np.random.default_rng(1).normal(0.0, 10.0, truth.channels.shape) * sk.scored_mask
    for own in (0.0, 0.5):
        out = fit_twists(sk, turned, other, change, own)
        rot, ref, got = (local_rotations(sk, c)[150] for c in (turned, other, out))
        axis = local_translations(sk, turned)[150, fore] / np.linalg.norm(local_translations(sk, turned)[150, fore])
        grid = Rotation.from_rotvec(np.linspace(-np.pi, np.pi, 3601)[:, None] * axis).as_matrix()
        r_j, r_c = (
            np.concatenate([rot[arm] @ grid, got[arm][None]]),
            np.concatenate([np.swapaxes(grid, 1, 2) @ rot[fore], got[fore][None]]),
        )
        value = (ref[fore] * r_c).sum(axis=(1, 2)) + own * (ref[arm] * r_j).sum(axis=(1, 2))  # tr(R̂ᵀ R) terms
        assert value[:-1].max() - 1e-12 <= value[-1] <= value[:-1].max() + 1e-5  # the grid steps 0.1°


def test_fit_twist_moves_no_point_of_the_fallback_and_turns_it_towards_the_reference(parts) -> None:
    """``fit_twist`` in a gated gap: the PCA fallback turned by ``fit_twists`` towards the twist reference (the
    kNN estimate, ``twist="knn"``): its joint and End Site positions stay as they were, the upper arm's and
    forearm's angles change; observed samples stay as they were."""
    truth = parts[1]
    sk = truth.skeleton
    noisy, mask, db, knn_only = _gated_arm_case(parts)
    gate = {**_PLAIN, "limb_gate": 1e-6, "twist": "knn", "gated_twist": True}
    plain, _ = fill_angles(noisy, mask, db, WindowSettings(**gate))
    for own in (0.0, 1.0):
        fitted, _ = fill_angles(noisy, mask, db, WindowSettings(**{**gate, "fit_twist": own}))
        assert np.array_equal(fitted[~mask], noisy.channels[~mask])
        want = fit_twists(sk, plain, knn_only, mask & sk.scored_mask[None], own)
        assert np.allclose(fitted[mask], want[mask], atol=1e-9)
        pos = [joint_positions(noisy.with_channels(c), end_sites=True) for c in (plain, fitted)]
        assert np.abs(pos[0] - pos[1]).max() < 1e-6  # cm
        for j in (sk.names.index("LeftArm"), sk.names.index("LeftForeArm")):
            cols = sk.joint_channels(j)
            assert np.abs(wrap_deg(fitted - plain))[:, cols][mask[:, cols]].max() > 1.0


def test_pca_pair_is_the_mean_of_the_two_pca_fills(parts) -> None:
    """``pca_pair``: the fallback's positions are the mean of the PCA fill with every known point and the fill
    with the joints whose own rotation is missing hidden too (the ``pca`` baseline's view); the two differ, so
    the mean differs from either; observed samples stay as they were, and the fill is exact with the truth in
    the database."""
    truth = parts[1]
    sk = truth.skeleton
    noisy, mask = _segment_gap(truth, "segment-gap:left-arm:1", seed=4)
    joint_missing = np.stack([mask[:, sk.joint_channels(j)].any(axis=1) for j in range(sk.n_joints)], axis=1)
    visible = points_visible(sk, joint_missing)
    hidden = own_hidden(sk, joint_missing)
    assert (visible & hidden).any()  # the upper arm's position is known, and hidden in the second view
    lerp = lerp_fill(noisy.channels, mask)
    pos = joint_positions(noisy.with_channels(lerp), end_sites=True)
    fills = [pca_fill(np.where(v[..., None], pos, np.nan), v) for v in (visible, visible & ~hidden)]
    assert np.nanmax(np.abs(fills[0] - fills[1])) > 0.1  # cm
    want = inverse_kinematics(noisy.with_channels(lerp), (fills[0] + fills[1]) / 2)
    got = pca_angles(noisy, mask, lerp, visible, hidden=hidden)
    assert np.allclose(got[mask], want[mask], atol=1e-9) and np.array_equal(got[~mask], lerp[~mask])
    single = pca_angles(noisy, mask, lerp, visible)
    assert np.abs(wrap_deg(got - single))[mask].max() > 0.1
    other = SkeletonDatabase.from_motions([parts[0], parts[2]])
    gated, _ = fill_angles(noisy, mask, other, WindowSettings(**{**_PLAIN, "limb_gate": 1e-6, "pca_pair": True}))
    assert np.allclose(gated[mask], got[mask], atol=1e-9) and np.array_equal(gated[~mask], noisy.channels[~mask])
    db = SkeletonDatabase.from_motions([parts[0], truth.with_channels(truth.channels), parts[2]])
    db.names = ("part0", "copy of the truth", "part1800")
    for extra in ({"pca_pair": True}, {"fit_twist": 0.0}, {"fit_twist": 1.0, "pca_pair": True, "pca_gate": 1.0}):
        out, _ = fill_angles(noisy, mask, db, WindowSettings(**{**ANGLE_DEFAULTS, **extra}))
        assert _gap_rms(out, truth.channels, mask) < 1e-3
