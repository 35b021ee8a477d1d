"""Filter and windowing building blocks."""

from __future__ import annotations

import pytest
import torch

from mocapnet.nn.layers import (
    BLSTM,
    gaussian_filter,
    gaussian_weights,
    phase_groups,
    softmax_filter,
    unfold_taps,
    window_starts,
)


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


def _reference(x: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """The filter written out with the [B, C, T, K] taps: ``x [B, T, C]``, ``weights [B, C, T, K]``."""
    return (unfold_taps(x, (weights.shape[-1] - 1) // 2) * weights).sum(-1).transpose(1, 2)


@pytest.mark.parametrize("length", [1, 7, 40])
def test_tap_by_tap_filters_equal_the_unfolded_kernels(length):
    torch.manual_seed(1)
    x = torch.randn(2, length, 3) * 20.0
    log_sigma = torch.empty(2, length, 3).uniform_(-5.0, 5.0)
    expected = _reference(x, gaussian_weights(log_sigma.transpose(1, 2), 15))
    torch.testing.assert_close(gaussian_filter(x, log_sigma, 15), expected, rtol=1e-5, atol=1e-4)
    logits = torch.randn(2, length, 3, 31) * 4.0
    expected = _reference(x, torch.softmax(logits.permute(0, 2, 1, 3), -1))
    got = softmax_filter(x, lambda k: logits[..., k + 15], 15, logits.amax(-1))
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-4)


def test_filters_identity_and_constant():
    x = torch.randn(2, 20, 3)
    torch.testing.assert_close(gaussian_filter(x, torch.full((2, 20, 3), -5.0), 15), x)
    const = torch.full((1, 20, 1), 7.0)
    torch.testing.assert_close(gaussian_filter(const, torch.randn(1, 20, 1), 15), const)
    logits = torch.randn(1, 20, 1, 31)
    torch.testing.assert_close(softmax_filter(const, lambda k: logits[..., k + 15], 15, logits.amax(-1)), const)


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
