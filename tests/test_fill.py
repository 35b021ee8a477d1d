import numpy as np

from mocapnet.fill import gap_fill, lerp_fill, spline_fill


def test_gap_fill_takes_the_spline_on_short_gaps_and_the_line_on_long_ones():
    t = np.arange(200.0)
    x = np.stack([np.sin(t / 9.0) * 40, np.cos(t / 13.0) * 25, t * 0.1], axis=1)
    mask = np.zeros(x.shape, dtype=bool)
    mask[20:24, :2] = True  # 4 frames: short
    mask[100:160, :2] = True  # 60 frames: long
    mask[50:53, 2] = True  # another column, another pattern
    noisy = np.where(mask, np.nan, x)
    out = gap_fill(noisy, mask, spline_max=15)
    lerp, spline = lerp_fill(noisy, mask), spline_fill(noisy, mask)
    np.testing.assert_array_equal(out[20:24, :2], spline[20:24, :2])
    np.testing.assert_array_equal(out[100:160, :2], lerp[100:160, :2])
    np.testing.assert_array_equal(out[50:53, 2], spline[50:53, 2])
    np.testing.assert_array_equal(out[~mask], x[~mask])  # observed samples untouched
    assert np.abs(out[20:24, 0] - x[20:24, 0]).max() < np.abs(lerp[20:24, 0] - x[20:24, 0]).max()
    np.testing.assert_array_equal(gap_fill(noisy, mask, spline_max=0), lerp)
    np.testing.assert_array_equal(gap_fill(noisy, mask, 15, interpolated=(lerp, spline)), out)  # given, not recomputed
