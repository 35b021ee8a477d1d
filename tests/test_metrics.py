import numpy as np

from mocapnet.evaluate import metrics


def test_wrapped_difference():
    np.testing.assert_allclose(metrics.wrapped_diff(179.0, -179.0), -2.0)
    np.testing.assert_allclose(metrics.wrapped_diff(10.0, 370.0), 0.0)


def test_angle_and_gap_errors():
    truth = np.zeros((10, 3))
    cleaned = truth.copy()
    cleaned[:, 0] = 3.0
    scored = np.array([True, True, False])
    assert metrics.angle_err_deg(cleaned, truth, scored) == np.sqrt(9 / 2)
    mask = np.zeros_like(truth, dtype=bool)
    assert np.isnan(metrics.gap_err_deg(cleaned, truth, mask))
    mask[2:4, 0] = True
    assert metrics.gap_err_deg(cleaned, truth, mask) == 3.0


def test_rotation_and_position_errors(cmu_short):
    m = cmu_short
    assert metrics.rot_err_deg(m, m.channels) < 1e-6
    assert metrics.pos_err_cm(m, m.channels) < 1e-9
    shifted = m.channels.copy()
    col = m.skeleton.channel_labels.index("LeftLeg.Xrotation")
    shifted[:, col] += 10.0
    assert 0 < metrics.rot_err_deg(m, shifted) < 10.0
    assert metrics.pos_err_cm(m, shifted) > 0.1
    # the root is context: moving it is not scored
    root = m.channels.copy()
    root[:, 0] += 50.0
    assert metrics.pos_err_cm(m, root) < 1e-9


def test_point_error():
    truth = np.zeros((5, 2, 3))
    filled = truth.copy()
    filled[1, 0] = [3.0, 4.0, 0.0]
    missing = np.zeros((5, 2), dtype=bool)
    missing[1, 0] = missing[2, 0] = True
    assert metrics.point_err_cm(filled, truth, missing) == 2.5
