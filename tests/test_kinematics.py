import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.kinematics import (
    inverse_kinematics,
    joint_positions,
    matrix_to_euler,
    rest_positions,
    wrap_deg,
    wrap_near,
)
from mocapnet.motion import Skeleton


def test_fk_of_rest_pose_is_offsets(cmu):
    zero = np.zeros((1, cmu.skeleton.n_channels))
    pos = joint_positions(cmu, zero, end_sites=True)[0] / cmu.skeleton.cm_per_unit
    np.testing.assert_allclose(pos, rest_positions(cmu.skeleton), atol=1e-9)


def test_fk_chain_by_hand():
    sk = Skeleton(("a", "b"), (-1, 0), np.array([[0.0, 0, 0], [1.0, 0, 0]]), (("Zrotation",), ("Zrotation",)))
    from mocapnet.motion import Motion

    m = Motion(sk, np.array([[90.0, 0.0]]), 30.0)
    np.testing.assert_allclose(joint_positions(m)[0, 1], [0, 1, 0], atol=1e-12)


def test_cmu_thigh_is_40cm(cmu):
    pos = joint_positions(cmu)
    names = cmu.skeleton.names
    thigh = np.linalg.norm(pos[:, names.index("LeftLeg")] - pos[:, names.index("LeftUpLeg")], axis=-1)
    np.testing.assert_allclose(thigh, 40.4, atol=0.5)


def test_matrix_to_euler_nearest_solution():
    rng = np.random.default_rng(0)
    for seq in ("ZXY", "ZYX", "XYZ"):
        ang = rng.uniform(-170, 170, (50, 3))
        ang[:, 1] = rng.uniform(-80, 80, 50)
        mats = Rotation.from_euler(seq, ang, degrees=True).as_matrix()
        ref = ang + 360.0 * rng.integers(-2, 3, ang.shape)
        np.testing.assert_allclose(matrix_to_euler(mats, seq, reference=ref), ref, atol=1e-8)


def test_ik_of_clean_positions_is_identity(cmu_short, bandai):
    for m in (cmu_short, bandai):
        ch = inverse_kinematics(m, joint_positions(m, end_sites=True))
        np.testing.assert_allclose(ch, m.channels, atol=1e-6)


def _scipy_local_rotations(skeleton, channels):
    """The per-joint scipy conversion the vectorised one replaces."""
    from mocapnet.kinematics import rotation_sequence

    out = np.broadcast_to(np.eye(3), (channels.shape[0], skeleton.n_joints, 3, 3)).copy()
    for j in range(skeleton.n_joints):
        seq, cols = rotation_sequence(skeleton, j)
        if seq:
            out[:, j] = Rotation.from_euler(seq, channels[:, cols], degrees=True).as_matrix()
    return out


def test_euler_to_matrix_equals_scipy_for_every_order():
    from itertools import permutations

    from mocapnet.kinematics import euler_to_matrix

    rng = np.random.default_rng(1)
    ang = rng.uniform(-720, 720, (40, 5, 3))
    for seq in ["".join(p) for p in permutations("XYZ")] + ["ZXZ", "YXY"]:
        want = Rotation.from_euler(seq, ang.reshape(-1, 3), degrees=True).as_matrix().reshape(40, 5, 3, 3)
        np.testing.assert_allclose(euler_to_matrix(ang, seq), want, rtol=0, atol=1e-12)
    for seq in ("X", "ZY"):
        part = ang[..., : len(seq)]
        want = Rotation.from_euler(seq, part.reshape(-1, len(seq)), degrees=True).as_matrix().reshape(40, 5, 3, 3)
        np.testing.assert_allclose(euler_to_matrix(part, seq), want, rtol=0, atol=1e-12)


def test_local_rotations_and_fk_match_the_per_joint_scipy_path(cmu_short):
    from mocapnet.kinematics import global_transforms, local_rotations, local_translations

    rng = np.random.default_rng(2)
    ch = cmu_short.channels + rng.normal(0, 30, cmu_short.channels.shape)
    sk = cmu_short.skeleton
    want = _scipy_local_rotations(sk, ch)
    np.testing.assert_allclose(local_rotations(sk, ch), want, rtol=0, atol=1e-12)
    rot_g, pos_g = global_transforms(sk, ch)
    trans = local_translations(sk, ch)
    np.testing.assert_array_equal(pos_g[:, 0], trans[:, 0])
    for j, p in enumerate(sk.parents):  # the joint-by-joint chain, parent first
        if p >= 0:
            np.testing.assert_allclose(rot_g[:, j], rot_g[:, p] @ want[:, j], rtol=0, atol=1e-12)
            want_pos = pos_g[:, p] + np.einsum("tab,tb->ta", rot_g[:, p], trans[:, j])
            np.testing.assert_allclose(pos_g[:, j], want_pos, rtol=0, atol=1e-9)


def test_mixed_axis_orders_and_translations_in_one_skeleton():
    from mocapnet.kinematics import local_rotations, local_translations
    from mocapnet.motion import Motion

    sk = Skeleton(
        ("root", "a", "b", "c"),
        (-1, 0, 1, 0),
        np.array([[0.0, 0, 0], [0, 10, 0], [0, 10, 0], [5, 0, 0]]),
        (
            ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
            ("Xrotation", "Yrotation", "Zrotation"),
            ("Yposition", "Zrotation"),
            (),
        ),
    )
    rng = np.random.default_rng(3)
    m = Motion(sk, rng.uniform(-90, 90, (7, sk.n_channels)), 30.0)
    np.testing.assert_allclose(local_rotations(sk, m.channels), _scipy_local_rotations(sk, m.channels), atol=1e-12)
    trans = local_translations(sk, m.channels)
    np.testing.assert_array_equal(trans[:, 0], m.channels[:, :3])
    np.testing.assert_array_equal(trans[:, 2, 1], m.channels[:, 9])
    np.testing.assert_array_equal(trans[:, 3], np.broadcast_to(sk.offsets[3], (7, 3)))


def test_geodesic_angle_is_accurate_at_every_size():
    from mocapnet.kinematics import geodesic_deg

    a = Rotation.random(500, random_state=0)
    for angle_rad in (1e-9, 1e-4, 0.5, 3.0):
        axis = np.random.default_rng(1).normal(size=(500, 3))
        step = Rotation.from_rotvec(axis / np.linalg.norm(axis, axis=1, keepdims=True) * angle_rad)
        got = geodesic_deg(a.as_matrix(), (a * step).as_matrix())
        np.testing.assert_allclose(got, np.degrees(angle_rad), rtol=1e-6, atol=1e-12)


def test_wrap_deg_and_wrap_near_ranges():
    x = np.array([-540.0, -180.0, -179.5, 0.0, 179.5, 180.0, 359.0, 720.25])
    np.testing.assert_array_equal(wrap_deg(x), [-180.0, -180.0, -179.5, 0.0, 179.5, -180.0, -1.0, 0.25])
    center = np.array([[10.0], [-170.0]])  # broadcast against x
    near = wrap_near(x, center)
    assert near.shape == (2, len(x))
    assert ((near > center - 180.0) & (near <= center + 180.0)).all()
    np.testing.assert_array_equal(np.round((near - x) / 360.0) * 360.0, near - x)  # moved by whole turns
    np.testing.assert_array_equal(wrap_near(np.array([190.0, -170.0]), 10.0), [190.0, 190.0])  # c + 180 kept
