"""Left/right mirroring (mocapnet.mirror): exact mirrored positions on rigs whose joint frames differ joint to
joint, involution, name pairing, refusals."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mocapnet.kinematics import global_transforms, joint_positions, local_rotations, matrix_to_euler
from mocapnet.mirror import fit_mirror, mirror_motion, mirror_partners
from mocapnet.motion import Motion, Skeleton

ROOT = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
ROT = ("Zrotation", "Xrotation", "Yrotation")
# name, parent, offset in a world-aligned rest pose (Y up, left = +X)
BODY = (
    ("Hips", -1, (0, 0, 0)),
    ("Spine", 0, (0, 10, 0)),
    ("Head", 1, (0, 12, 0)),
    ("LeftArm", 1, (5, 10, 0)),
    ("LeftForeArm", 3, (9, 0, 0)),
    ("RightArm", 1, (-5, 10, 0)),
    ("RightForeArm", 5, (-9, 0, 0)),
    ("LeftUpLeg", 0, (3, -2, 0)),
    ("LeftLeg", 7, (0, -20, 0)),
    ("RightUpLeg", 0, (-3, -2, 0)),
    ("RightLeg", 9, (0, -20, 0)),
)


def _skeleton(names=None, offsets=None) -> Skeleton:
    names = names or [b[0] for b in BODY]
    offsets = np.array([b[2] for b in BODY], dtype=float) if offsets is None else offsets
    return Skeleton(tuple(names), tuple(b[1] for b in BODY), offsets, (ROOT,) + (ROT,) * (len(BODY) - 1))


def _proper_axis_rotations() -> list[np.ndarray]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[range(3), perm] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


def _motion(seed: int = 0, frames: int = 600, conventions: bool = True) -> Motion:
    """A random motion of the body above; with ``conventions`` every joint's frame is re-expressed by its own
    axis rotation (left and right differently), as a rig like Bandai's is: same positions, other channels."""
    rng = np.random.default_rng(seed)
    sk = _skeleton()
    ch = np.zeros((frames, sk.n_channels))
    ch[:, :3] = np.cumsum(rng.normal(0, 0.5, (frames, 3)), axis=0) + [0, 22, 0]
    ch[:, 3:] = rng.uniform(-40, 40, (frames, sk.n_channels - 3))
    ch[:, 5] = rng.uniform(-180, 180, frames)  # heading (Y) of the hips: any direction
    if not conventions:
        return Motion(sk, ch, 30.0, "canonical")
    basis = _proper_axis_rotations()
    frame = np.array([basis[rng.integers(len(basis))] for _ in BODY])
    rot_l = local_rotations(sk, ch)
    offsets = sk.offsets.copy()
    out = ch.copy()
    for j, (_, p, _) in enumerate(BODY):
        b_p = np.eye(3) if p < 0 else frame[p]
        offsets[j] = b_p.T @ sk.offsets[j]
        if p < 0:
            out[:, :3] = ch[:, :3]
        rotated = b_p.T @ rot_l[:, j] @ frame[j]
        cols = sk.joint_channels(j)[-3:]
        out[:, cols] = np.unwrap(matrix_to_euler(rotated, "ZXY"), period=360.0, axis=0)
    conv = _skeleton(offsets=offsets)
    motion = Motion(conv, out, 30.0, "conventions")
    np.testing.assert_allclose(joint_positions(motion), joint_positions(Motion(sk, ch, 30.0)), atol=1e-9)
    return motion


def _assert_mirrored(motion: Motion, mirror) -> Motion:
    """``motion`` mirrored, checked: every joint at the reflection of its partner, twice = the same rotations."""
    mirrored = mirror_motion(motion, mirror)
    expected = (joint_positions(motion) @ mirror.world.T)[:, mirror.partner]
    np.testing.assert_allclose(joint_positions(mirrored), expected, atol=1e-9)
    twice = local_rotations(motion.skeleton, mirror_motion(mirrored, mirror).channels)
    np.testing.assert_allclose(twice, local_rotations(motion.skeleton, motion.channels), atol=1e-9)
    return mirrored


@pytest.mark.parametrize("seed", range(6))
def test_any_per_joint_frame_convention_mirrors_exactly(seed):
    """Random per-joint frames need reflections that are not their own inverse (rotoreflections) as often as
    not: the local rotation is ``A_p^T R A_j``, not ``A_p R A_j``."""
    motion = _motion(seed=seed)
    _assert_mirrored(motion, fit_mirror([motion]))


@pytest.mark.parametrize("conventions", [False, True])
def test_mirrored_positions_are_the_reflection_with_sides_swapped(conventions):
    motion = _motion(conventions=conventions)
    mirror = fit_mirror([motion])
    mirrored = mirror_motion(motion, mirror)
    assert mirrored.name == f"{motion.name}#mirror"
    expected = (joint_positions(motion) @ mirror.world.T)[:, mirror.partner]
    np.testing.assert_allclose(joint_positions(mirrored), expected, atol=1e-9)
    assert mirror.world[1, 1] == 1.0  # Y is up: the reflection is through a vertical plane
    # mirrored twice is the same motion: equal rotations, channels equal up to whole turns
    twice = mirror_motion(mirrored, mirror)
    rot_a, rot_b = local_rotations(motion.skeleton, motion.channels), local_rotations(motion.skeleton, twice.channels)
    np.testing.assert_allclose(rot_b, rot_a, atol=1e-9)
    # with world-aligned frames the map is the textbook one (negate X, and the Z and Y rotations, swap sides)
    # and twice is the identity on the channels themselves
    if not conventions:
        np.testing.assert_allclose(twice.channels, motion.channels, atol=1e-9)
        np.testing.assert_array_equal(mirror.frames, np.broadcast_to(np.diag([-1.0, 1, 1]), mirror.frames.shape))
        cols = motion.skeleton.joint_channels(3)
        np.testing.assert_allclose(
            mirrored.channels[:, motion.skeleton.joint_channels(5)], motion.channels[:, cols] * [-1, 1, -1]
        )


def test_mirroring_keeps_the_root_translation_but_its_lateral_axis():
    motion = _motion(conventions=False)
    mirrored = mirror_motion(motion, fit_mirror([motion]))
    np.testing.assert_allclose(mirrored.channels[:, :3], motion.channels[:, :3] * [-1, 1, 1])


@pytest.mark.parametrize(
    "left,right", [("Left{}", "Right{}"), ("{}_L", "{}_R"), ("L_{}", "R_{}"), ("l{}", "r{}"), ("{}.L", "{}.R")]
)
def test_partners_pair_by_name_in_common_conventions(left, right):
    def rename(name: str) -> str:
        for side, pattern in (("Left", left), ("Right", right)):
            if name.startswith(side):
                return pattern.format(
                    name[len(side) :].lower() if pattern == "l{}" or pattern == "r{}" else name[len(side) :]
                )
        return name

    sk = _skeleton(names=[rename(b[0]) for b in BODY])
    partner = mirror_partners(sk)
    assert [sk.names[p] for p in partner[[3, 4, 7, 8]]] == [sk.names[i] for i in (5, 6, 9, 10)]
    assert list(partner[:3]) == [0, 1, 2]


def test_skeletons_that_cannot_be_mirrored_are_refused():
    names = [b[0] for b in BODY]
    with pytest.raises(ValueError, match="no left/right"):
        mirror_partners(_skeleton(names=[n.replace("Left", "A").replace("Right", "B") for n in names]))
    with pytest.raises(ValueError, match="'LeftArm' is a side joint with no partner"):
        mirror_partners(_skeleton(names=[n.replace("RightArm", "OtherArm") for n in names]))
    with pytest.raises(ValueError, match="parents"):  # partners whose parents are not partners
        mirror_partners(
            _skeleton(names=[{"LeftForeArm": "LeftLeg", "LeftLeg": "LeftForeArm"}.get(n, n) for n in names])
        )
    motion = _motion(conventions=False)
    bent = motion.skeleton.offsets.copy()
    bent[6] = (0, 9, 0)  # right forearm at 90° from the mirrored left one
    crooked = Motion(_skeleton(offsets=bent), motion.channels, 30.0, "crooked")
    with pytest.raises(ValueError, match="(Left|Right)Arm.*not mirror"):
        fit_mirror([crooked])
    other = Motion(_skeleton(names=[n + "x" for n in names]), motion.channels, 30.0)
    with pytest.raises(ValueError, match="skeleton differs"):
        mirror_motion(other, fit_mirror([motion]))


def test_bandai_rig_mirrors_exactly(shared):
    """Bandai's joint frames differ joint to joint: every position is the mirror image to rounding."""
    from mocapnet.io.bvh import read_bvh

    clips = [read_bvh(f) for f in sorted((shared / "bvh" / "bandai_namco_2").glob("*.bvh.gz"))[::250]]
    mirror = fit_mirror(clips)
    for clip in clips[:3]:
        mirrored = mirror_motion(clip, mirror)
        expected = (joint_positions(clip) @ mirror.world.T)[:, mirror.partner]
        np.testing.assert_allclose(joint_positions(mirrored), expected, atol=1e-9)
    assert mirror.mismatch_deg.max() < 45.0
    _, pos = global_transforms(clips[0].skeleton, clips[0].channels[:1])
    assert pos.shape[1] == len(mirror.partner)


def _under_reference(motion: Motion, shift: np.ndarray | None = None) -> Motion:
    """``motion`` under a position-only "Reference" root (a common export layout), moved by ``shift [T, 3]``
    (via the hips' translation) while the reference stays at the origin."""
    sk = motion.skeleton
    names = ("Reference",) + sk.names
    parents = (-1,) + tuple(p + 1 for p in sk.parents)
    channels = (("Xposition", "Yposition", "Zposition"),) + sk.channels
    out = np.concatenate([np.zeros((motion.n_frames, 3)), motion.channels], axis=1)
    if shift is not None:
        out[:, 3:6] += shift
    return Motion(Skeleton(names, parents, np.vstack([np.zeros(3), sk.offsets]), channels), out, 30.0, "ref")


def test_a_position_only_root_keeps_its_parent_frame_and_travel_does_not_turn_the_mirror_over():
    motion = _under_reference(_motion())
    mirror = fit_mirror([motion])
    np.testing.assert_array_equal(mirror.frames[0], mirror.world)  # no rotation channel: A = the world's
    _assert_mirrored(motion, mirror)
    # travelling 400 units along X while the reference root stays put: X must not be taken for up
    far = _under_reference(_motion(conventions=False), np.linspace(0, 400, 600)[:, None] * [1.0, 0.0, 0.0])
    mirror = fit_mirror([far])
    assert mirror.world[1, 1] == 1.0 and mirror.world[0, 0] == -1.0
    _assert_mirrored(far, mirror)


def test_left_and_right_may_use_other_rotation_orders_and_fewer_channels():
    motion = _motion(conventions=False)
    sk, rot = motion.skeleton, local_rotations(motion.skeleton, motion.channels)
    orders = list(sk.channels)
    out = motion.channels.copy()
    for j in (5, 6):  # the right arm in XYZ order
        orders[j] = ("Xrotation", "Yrotation", "Zrotation")
        out[:, sk.joint_channels(j)] = matrix_to_euler(rot[:, j], "XYZ")
    mixed = Motion(Skeleton(sk.names, sk.parents, sk.offsets, tuple(orders)), out, 30.0, "orders")
    _assert_mirrored(mixed, fit_mirror([mixed]))
    # knees with one rotation channel (ASF-style): a sign change, done exactly
    knees = list(sk.channels)
    for j in (8, 10):
        knees[j] = ("Xrotation",)
    one = Skeleton(sk.names, sk.parents, sk.offsets, tuple(knees))
    keep = [
        c for j in range(sk.n_joints) for c in (sk.joint_channels(j)[1:2] if j in (8, 10) else sk.joint_channels(j))
    ]
    bent = Motion(one, motion.channels[:, keep], 30.0, "knees")
    knee_cols = [one.joint_channels(8)[0], one.joint_channels(10)[0]]
    mirrored = _assert_mirrored(bent, fit_mirror([bent]))
    np.testing.assert_array_equal(mirrored.channels[:, knee_cols[1]], bent.channels[:, knee_cols[0]])


def test_3ds_max_biped_names_pair():
    names = [b[0].replace("Left", "Bip01 L ").replace("Right", "Bip01 R ") for b in BODY]
    sk = _skeleton(names=names)
    assert [sk.names[p] for p in mirror_partners(sk)[[3, 7]]] == ["Bip01 R Arm", "Bip01 R UpLeg"]
