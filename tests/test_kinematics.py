import numpy as np
from scipy.spatial.transform import Rotation

from mocapnet.kinematics import inverse_kinematics, joint_positions, matrix_to_euler, rest_positions
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
