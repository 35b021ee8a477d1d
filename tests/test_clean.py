"""One-file cleaning: masks are bool or 0/1 only, output names follow the input's format, errors are one line."""

from __future__ import annotations

import numpy as np
import pytest

from mocapnet.clean import CleanOptions, check_output_name, clean_file, read_mask
from mocapnet.cli import main
from mocapnet.io.atomic import MocapFileError
from mocapnet.io.bvh import format_bvh


@pytest.fixture()
def short_bvh(tmp_path, cmu):
    path = tmp_path / "walk.bvh"
    path.write_text(format_bvh(cmu.with_channels(cmu.channels[:60])))
    return path


@pytest.fixture()
def short_motion(cmu):
    return cmu.with_channels(cmu.channels[:60])


@pytest.mark.parametrize(
    "values",
    [
        np.full((60, 3), 0.5),
        np.array([[np.nan]]),
        np.array(["yes", "no"]),
        np.array([0, 1, 2]),
        np.zeros((0, 93), dtype=bool),
        np.zeros((60, 93), dtype=np.float32),
    ],
    ids=["half", "nan", "strings", "int-2", "empty", "float-zeros"],
)
def test_mask_of_anything_but_bool_or_01_is_refused(tmp_path, short_motion, values):
    path = tmp_path / "mask.npy"
    np.save(path, values)
    with pytest.raises(MocapFileError, match="mask"):
        read_mask(path, short_motion)


def test_pickled_and_npz_masks_are_refused(tmp_path, short_motion):
    pickled = tmp_path / "obj.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(MocapFileError, match="obj.npy"):
        read_mask(pickled, short_motion)
    archive = tmp_path / "m.npz"
    np.savez(archive, mask=np.zeros(short_motion.channels.shape, dtype=bool))
    with pytest.raises(MocapFileError, match="npz archive"):
        read_mask(archive, short_motion)
    not_numpy = tmp_path / "m.npy"
    not_numpy.write_text("True False")
    with pytest.raises(MocapFileError, match="not a NumPy"):
        read_mask(not_numpy, short_motion)
    with pytest.raises(MocapFileError, match="absent.npy: no such mask file"):
        read_mask(tmp_path / "absent.npy", short_motion)


def test_bool_and_01_masks_in_both_shapes(tmp_path, short_motion):
    sk = short_motion.skeleton
    per_channel = np.zeros(short_motion.channels.shape, dtype=np.int8)
    per_channel[10:20, 5] = 1
    np.save(tmp_path / "c.npy", per_channel)
    got = read_mask(tmp_path / "c.npy", short_motion)
    assert got.dtype == bool and got.sum() == 10
    per_joint = np.zeros((short_motion.n_frames, sk.n_joints), dtype=bool)
    per_joint[5:9, 2] = True
    np.save(tmp_path / "j.npy", per_joint)
    got = read_mask(tmp_path / "j.npy", short_motion)
    assert got.sum() == 4 * len(sk.channels[2])
    np.save(tmp_path / "bad.npy", np.zeros((7, 7), dtype=bool))
    with pytest.raises(MocapFileError, match="fits neither"):
        read_mask(tmp_path / "bad.npy", short_motion)


@pytest.mark.parametrize("name", ["out", "out.c3d", "out.bvh.txt", ""])
def test_output_name_must_match_the_input_format(tmp_path, short_bvh, name):
    out = tmp_path / name if name else ""
    with pytest.raises(MocapFileError, match="output name must end in" if name else "output path is empty"):
        check_output_name(short_bvh, out)


def test_output_case_insensitive_and_never_the_input(tmp_path, short_bvh):
    check_output_name(short_bvh, tmp_path / "OUT.BVH")
    check_output_name(tmp_path / "take.C3D", tmp_path / "out.c3d")
    with pytest.raises(MocapFileError, match="same as the input"):
        check_output_name(short_bvh, short_bvh)


def test_clean_file_with_a_mask_fills_only_masked_samples(tmp_path, short_bvh, short_motion):
    mask = np.zeros(short_motion.channels.shape, dtype=bool)
    mask[20:30, 10] = True
    np.save(tmp_path / "mask.npy", mask)
    result = clean_file(short_bvh, tmp_path / "out.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "mask.npy")))
    assert result.samples_filled == 10 and result.frames == 60 and (tmp_path / "out.bvh").exists()


def test_cli_errors_are_one_line_exit_2_and_write_nothing(tmp_path, short_bvh, capsys):
    bad_mask = tmp_path / "mask.npy"
    np.save(bad_mask, np.full((60, 93), 0.5))
    cases = [
        ["clean", str(short_bvh), "-o", str(tmp_path / "out.bvh"), "--method", "lerp", "--mask", str(bad_mask)],
        ["clean", str(short_bvh), "-o", str(tmp_path / "out"), "--method", "lerp"],
        ["clean", str(tmp_path / "missing.bvh"), "-o", str(tmp_path / "out.bvh")],
        ["clean", str(short_bvh), "-o", str(tmp_path / "x.c3d"), "--method", "lerp"],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("mocapnet: error:") and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mask.npy", "walk.bvh"]


def test_c3d_report_numbers_frames_as_the_file_does(tmp_path):
    from mocapnet.io.c3d_raw import read_layout
    from mocapnet.methods.autofill import summary_table
    from tests.conftest import SAMPLE_C3D_NAN

    result = clean_file(SAMPLE_C3D_NAN, tmp_path / "out.c3d", CleanOptions())
    assert result.details["file_first_frame"] == read_layout(SAMPLE_C3D_NAN).first_frame
    gap = {"marker": "M1", "method": None, "ratio": None, "filled_frames": 0, "unfilled_spans": [[10, 19]]}
    gap["tried"] = ["rigid: fewer than 3 partners"]
    assert "frames 1377-1386 (10 frames)" in summary_table([gap], first_frame=1367)


def test_default_clean_of_a_skeleton_without_networks_runs_the_cross_validated_gaussian(tmp_path, cmu):
    """A BVH whose skeleton no shipped network knows (here the CMU rig with one joint renamed) is cleaned by
    default with gaussian-cv, and the result says so and why; its unscored channels and its gaps'
    neighbours stay as they were. Asking for ebf by name still fails with the skeleton named."""
    from mocapnet.io import read_bvh

    clip = cmu.with_channels(cmu.channels[:200])
    src = tmp_path / "other_rig.bvh"
    src.write_text(format_bvh(clip).replace("JOINT LeftFingerBase", "JOINT LeftFingerBaseX", 1))
    mask = np.zeros(clip.channels.shape, dtype=bool)
    scored = np.flatnonzero(clip.skeleton.scored_mask)
    mask[80:95, scored[4]] = True
    np.save(tmp_path / "mask.npy", mask)
    result = clean_file(src, tmp_path / "out.bvh", CleanOptions(mask=str(tmp_path / "mask.npy")))
    assert result.method == "gaussian-cv" and "no EBF shipped for this skeleton" in result.message
    assert result.details["auto"].startswith("no EBF shipped")
    out = read_bvh(tmp_path / "out.bvh").channels
    unscored = ~clip.skeleton.scored_mask
    np.testing.assert_allclose(out[:, unscored], clip.channels[:, unscored], atol=1e-4)
    assert np.isfinite(out).all() and not np.allclose(out[:, scored], clip.channels[:, scored], atol=1e-3)
    with pytest.raises(LookupError, match="no shipped 'ebf' checkpoint for this skeleton"):
        clean_file(src, tmp_path / "out2.bvh", CleanOptions(method="ebf"))
    assert not (tmp_path / "out2.bvh").exists()


def test_default_clean_of_a_shipped_skeleton_runs_its_networks(short_bvh, tmp_path):
    result = clean_file(short_bvh, tmp_path / "out.bvh", CleanOptions())
    assert result.method == "ebf" and "auto: EBF shipped for this skeleton (cmu120)" in result.message


def test_default_clean_at_another_frame_rate_than_the_network_runs_the_cross_validated_gaussian(tmp_path, cmu):
    """The shipped CMU networks count frames at 120 fps: a 30 fps file of the same rig gets gaussian-cv, and
    the reason names both rates."""
    import dataclasses

    src = tmp_path / "walk30.bvh"
    src.write_text(format_bvh(dataclasses.replace(cmu.with_channels(cmu.channels[:90]), fps=30.0)))
    result = clean_file(src, tmp_path / "out.bvh", CleanOptions())
    assert result.method == "gaussian-cv"
    assert "was trained at 120 fps, this clip is at 30 fps" in result.details["auto"]


def test_auto_with_a_checkpoint_is_one_clear_error(short_bvh, tmp_path):
    with pytest.raises(ValueError, match="--model names a checkpoint for a network method"):
        clean_file(short_bvh, tmp_path / "out.bvh", CleanOptions(method="auto", model="some.ckpt"))
    assert not (tmp_path / "out.bvh").exists()


def test_auto_plan_takes_an_index_entry_without_a_frame_rate(monkeypatch, short_motion):
    from mocapnet.methods import auto_angles

    entries = {"ebf": {"corpus": "x", "fps": 0.0}, "ebd": {"corpus": "x"}}
    monkeypatch.setattr(auto_angles, "shipped_methods", lambda skeleton: entries)
    assert auto_angles.auto_plan(short_motion.skeleton, 30.0, True)[0] == "ebd+ebf"
    assert auto_angles.auto_plan(short_motion.skeleton, 30.0, False)[0] == "ebf"


def test_a_channel_masked_in_every_frame_is_named_not_written(tmp_path, cmu):
    """Interpolation has nothing to go on in a channel masked in every frame: the error names the mask and the
    channel, and nothing is written."""
    clip = cmu.with_channels(cmu.channels[:120])
    src = tmp_path / "walk.bvh"
    src.write_text(format_bvh(clip))
    mask = np.zeros(clip.channels.shape, dtype=bool)
    mask[:, np.flatnonzero(clip.skeleton.scored_mask)[7]] = True
    np.save(tmp_path / "mask.npy", mask)
    label = clip.skeleton.channel_labels[np.flatnonzero(clip.skeleton.scored_mask)[7]]
    with pytest.raises(ValueError, match=rf"mask.npy: lerp cannot fill {label} \(masked in every frame\): 120 samples"):
        clean_file(src, tmp_path / "out.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "mask.npy")))
    assert not (tmp_path / "out.bvh").exists()


def test_model_replaces_the_checkpoint_and_keeps_the_method_options(short_bvh, tmp_path):
    """``--model`` swaps the checkpoint only: ``--method ebd:rehearse=0 --model X`` runs ``ebd=X:rehearse=0``."""
    from mocapnet.nn.checkpoints import CHECKPOINT_DIR

    ckpt = str(CHECKPOINT_DIR / "cmu120_ebd.ckpt")
    result = clean_file(short_bvh, tmp_path / "out.bvh", CleanOptions(method="ebd:rehearse=0", model=ckpt))
    assert result.method == f"ebd={ckpt}:rehearse=0"
    replaced = clean_file(short_bvh, tmp_path / "out2.bvh", CleanOptions(method="ebd=other.ckpt", model=ckpt))
    assert replaced.method == f"ebd={ckpt}"


def test_a_mask_on_the_root_and_positions_is_filled_linearly_and_said(tmp_path, cmu):
    """The methods fill scored rotations; gaps a mask marks in the root's (or any unscored) channels are
    interpolated linearly, counted in the message, and never written as the file's placeholder values. A ``[T, J]``
    mask marks every channel of its joints, the root's positions included."""
    from mocapnet.io import read_bvh

    clip = cmu.with_channels(cmu.channels[:120])
    src = tmp_path / "walk.bvh"
    src.write_text(format_bvh(clip))
    stored = read_bvh(src, unwrap=False).channels
    joints = np.zeros((clip.n_frames, clip.skeleton.n_joints), dtype=bool)
    joints[40:50, [0, 5]] = True  # the root and one scored joint
    np.save(tmp_path / "joints.npy", joints)
    result = clean_file(src, tmp_path / "out.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "joints.npy")))
    root = clip.skeleton.joint_channels(0)
    n_root = 10 * len(root)
    assert result.samples_filled == 10 * (len(root) + len(clip.skeleton.joint_channels(5)))
    assert f"{n_root} of them in unscored channels (root, positions, context joints) filled linearly" in result.message
    assert result.details["filled_linearly"] == n_root and result.details["held_at_ends"] == 0
    out = read_bvh(tmp_path / "out.bvh", unwrap=False).channels
    line = np.linspace(stored[39, root], stored[50, root], 12)[1:-1]
    np.testing.assert_allclose(out[40:50, root], line, atol=2e-6)  # not the stored values there
    assert np.abs(out[40:50, root] - stored[40:50, root]).max() > 1e-3
    np.testing.assert_array_equal(out[:40], stored[:40])
    # at the clip's start the interpolation can only hold the first observed value: said so
    joints[:5, 0] = True
    np.save(tmp_path / "start.npy", joints)
    result = clean_file(src, tmp_path / "start.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "start.npy")))
    assert result.details["held_at_ends"] == 5 * len(root)
    assert f"({5 * len(root)} at the clip's ends held at the nearest observed value)" in result.message
    # a root channel masked in every frame: named, nothing written
    every = np.zeros(clip.channels.shape, dtype=bool)
    every[:, root[0]] = True
    np.save(tmp_path / "every.npy", every)
    label = clip.skeleton.channel_labels[root[0]]
    with pytest.raises(ValueError, match=rf"linear interpolation cannot fill {label} \(masked in every frame\)") as err:
        clean_file(src, tmp_path / "none.bvh", CleanOptions(method="lerp", mask=str(tmp_path / "every.npy")))
    assert "ebd" not in str(err.value)  # no network fills the root
    assert not (tmp_path / "none.bvh").exists()


def test_auto_keeps_the_samples_of_a_keyframe_rate_file(tmp_path, cmu):
    """Below ``MIN_SMOOTH_FPS`` ``auto`` smooths nothing (frames a second apart are keyframes: cross-validation
    took motion for noise and turned an arm by 85°) and says why; gaps are still bridged."""
    import dataclasses

    from mocapnet.io import read_bvh
    from mocapnet.methods import auto_angles

    sparse = dataclasses.replace(cmu.with_channels(cmu.channels[:600:30]), fps=1.0, frame_time=None)
    src = tmp_path / "keys.bvh"
    src.write_text(format_bvh(sparse))
    result = clean_file(src, tmp_path / "out.bvh", CleanOptions())
    assert result.method == "lerp" and "at 1 fps frames are 1 s apart" in result.message
    np.testing.assert_array_equal(
        read_bvh(tmp_path / "out.bvh", unwrap=False).channels, read_bvh(src, unwrap=False).channels
    )
    method, why = auto_angles.auto_plan(sparse.skeleton, 5.0, True)
    assert method == "lerp" and why.endswith("gaps bridged linearly")
    assert auto_angles.auto_plan(sparse.skeleton, 24.0, False)[0] == auto_angles.FALLBACK
