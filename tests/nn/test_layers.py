"""Filter and windowing building blocks."""

from __future__ import annotations

import torch

from mocapnet.nn.layers import BLSTM, apply_filter, gaussian_weights, phase_groups, unfold_taps, window_starts


def test_unfold_taps_shape_and_edges():
    x = torch.arange(12.0).reshape(1, 6, 2)  # [B, T, C]
    taps = unfold_taps(x, half=2)
    assert taps.shape == (1, 2, 6, 5)
    assert taps[0, 0, 0].tolist() == [0.0, 0.0, 0.0, 2.0, 4.0]  # nearest-frame padding at the start
    assert taps[0, 1, 5].tolist() == [7.0, 9.0, 11.0, 11.0, 11.0]


def test_gaussian_weights_sum_to_one_and_limits():
    log_sigma = torch.tensor([[[-4.0, 0.0, 1.0, 4.0]]])  # [B, C, T]
    w = gaussian_weights(log_sigma, half=15)
    assert w.shape == (1, 1, 4, 31)
    torch.testing.assert_close(w.sum(-1), torch.ones(1, 1, 4))
    assert w[0, 0, 0, 15] > 0.999  # tiny sigma: identity
    assert (w[0, 0, 3] - 1 / 31).abs().max() < 1e-3  # huge sigma: box average
    torch.testing.assert_close(w.flip(-1), w)


def test_apply_filter_identity_and_constant():
    x = torch.randn(2, 20, 3)
    delta = torch.zeros(2, 3, 20, 31)
    delta[..., 15] = 1.0
    torch.testing.assert_close(apply_filter(x, delta), x)
    const = torch.full((1, 20, 1), 7.0)
    w = torch.softmax(torch.randn(1, 1, 20, 31), -1)
    torch.testing.assert_close(apply_filter(const, w), const)


def test_window_starts_and_phases():
    starts, width = window_starts(40, half=15)
    assert width == 31 and starts[0] == 0 and starts[20] == 5 and starts[-1] == 9
    starts, width = window_starts(10, half=15)
    assert width == 10 and (starts == 0).all()
    groups = phase_groups(10, 4)  # phases of lengths 3, 3, 2, 2
    assert sorted(g.shape for g in groups) == [(2, 2), (2, 3)]
    assert sorted(torch.cat([g.flatten() for g in groups]).tolist()) == list(range(10))


def test_blstm_windowed_equals_sequence_on_short_input():
    for stride, length in ((1, 31), (4, 120), (4, 37)):
        lstm = BLSTM(5, 6, layers=2, dropout=0.5, stride=stride).eval()
        codes = torch.randn(length, 5)
        with torch.no_grad():
            torch.testing.assert_close(lstm.windowed(codes, half=15), lstm(codes[None])[0])
