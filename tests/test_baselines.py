import numpy as np
import pytest

from mocapnet.corrupt import corrupt_motion, seed_for
from mocapnet.methods import MethodContext, build_method
from mocapnet.methods.baselines import gaussian_smooth, lerp_fill, spline_fill, tune_sigmas
from mocapnet.methods.registry import parse_method
from mocapnet.motion import Motion


def test_gaussian_matches_scipy_and_scales_with_fps():
    from scipy.ndimage import gaussian_filter1d

    x = np.random.default_rng(0).normal(size=(200, 3))
    np.testing.assert_allclose(
        gaussian_smooth(x, 0.058, 120.0), gaussian_filter1d(x, 0.058 * 120, axis=0, mode="nearest")
    )
    np.testing.assert_array_equal(gaussian_smooth(x, 0.0, 30.0), x)
    per_channel = gaussian_smooth(x, np.array([0.0, 0.1, 0.2]), 30.0)
    np.testing.assert_array_equal(per_channel[:, 0], x[:, 0])
    np.testing.assert_allclose(per_channel[:, 2], gaussian_filter1d(x[:, 2], 6.0, mode="nearest"))


def test_lerp_and_spline_fill():
    t = np.arange(100.0)
    x = np.stack([2 * t + 1, (t / 10) ** 3], axis=1)
    mask = np.zeros_like(x, dtype=bool)
    mask[30:50] = True
    noisy = np.where(mask, np.nan, x)
    np.testing.assert_allclose(lerp_fill(noisy, mask)[:, 0], x[:, 0])
    np.testing.assert_allclose(spline_fill(noisy, mask), x, atol=1e-9)  # a cubic is reproduced exactly
    edge = mask.copy()
    edge[:5] = True
    filled = lerp_fill(np.where(edge, np.nan, x), edge)
    assert np.isfinite(filled).all() and filled[0, 0] == x[5, 0]


def test_methods_only_touch_scored_channels(cmu_short):
    noisy, mask = corrupt_motion(cmu_short, "noise+gaps", np.random.default_rng(0))
    scored = cmu_short.skeleton.scored_mask
    names = (
        "gaussian-58ms",
        "gaussian-125ms",
        "lerp",
        "spline",
        "lerp+gaussian-58ms",
        "gaussian-58ms+check",
        "gaussian-cv",
    )
    for name in names:
        out = build_method(name).clean(cmu_short.with_channels(noisy), mask)
        assert np.isfinite(out).all(), name
        np.testing.assert_array_equal(out[:, ~scored], noisy[:, ~scored])
        np.testing.assert_array_equal(out[~mask & ~scored[None]], noisy[~mask & ~scored[None]])


def test_gaussian_beats_noisy(cmu_short):
    noisy, mask = corrupt_motion(cmu_short, "angular-0.5", np.random.default_rng(0))
    out = build_method("gaussian-58ms").clean(cmu_short.with_channels(noisy), mask)
    s = cmu_short.skeleton.scored_mask
    assert np.abs(out - cmu_short.channels)[:, s].mean() < 0.5 * np.abs(noisy - cmu_short.channels)[:, s].mean()


def test_checked_gaussian_keeps_clean_motion_and_smooths_noise(cmu_short):
    """gaussian-58ms+check: on noisy input it smooths almost as gaussian-58ms does; on the clean clip each
    channel changes by at most limit x the noise it shows (the plain Gaussian changes it far more)."""
    from mocapnet.selfcheck import noise_level

    s = cmu_short.skeleton.scored_mask
    checked, plain = build_method("gaussian-58ms+check"), build_method("gaussian-58ms")
    noisy, mask = corrupt_motion(cmu_short, "angular-0.5", np.random.default_rng(0))

    def err(out):
        return np.sqrt(np.mean((out - cmu_short.channels)[:, s] ** 2))

    noisy_motion = cmu_short.with_channels(noisy)
    assert err(checked.clean(noisy_motion, mask)) < 1.1 * err(plain.clean(noisy_motion, mask)) < err(noisy)
    none = np.zeros_like(mask)
    kept = checked.clean(cmu_short, none)[:, s] - cmu_short.channels[:, s]
    cap = build_method("gaussian-58ms+check:limit=1").clean(cmu_short, none)[:, s] - cmu_short.channels[:, s]
    level = noise_level(cmu_short.channels[:, s])
    np.testing.assert_array_less(np.sqrt(np.mean(cap**2, axis=0)), level + 1e-9)
    smoothed = plain.clean(cmu_short, none)[:, s] - cmu_short.channels[:, s]
    assert np.sqrt(np.mean(kept**2)) < 0.5 * np.sqrt(np.mean(smoothed**2))
    with pytest.raises(ValueError, match="limit must be positive"):
        build_method("gaussian-58ms+check:limit=0")


def test_gaussian_tuned_picks_per_channel_sigma(cmu):
    clips = [Motion(cmu.skeleton, cmu.channels[i : i + 500], cmu.fps, f"c{i}") for i in range(0, 2000, 500)]
    sig = tune_sigmas(clips, "angular-0.5")
    assert sig.shape == (cmu.skeleton.n_channels,)
    live = cmu.skeleton.scored_mask & (cmu.channels.std(axis=0) > 1.0)
    assert (sig[live] > 0).all()
    assert (sig[~cmu.skeleton.scored_mask] == 0).all()
    method = build_method("gaussian-tuned", MethodContext(train=clips, corruption="angular-0.5"))
    with pytest.raises(ValueError, match="training clips"):
        build_method("gaussian-tuned", MethodContext())
    assert method.space == "angles"


def test_parse_method_strings():
    assert parse_method("gaussian-58ms") == ("gaussian-58ms", {})
    assert parse_method("knn:k=8,levels=3,database=/a/b") == ("knn", {"k": 8, "levels": 3, "database": "/a/b"})
    words = parse_method("knn:gated_twist=false,offset=True,short_chain=none,pca_gate=NULL,fallback=pca")
    assert words == (
        "knn",
        {"gated_twist": False, "offset": True, "short_chain": None, "pca_gate": None, "fallback": "pca"},
    )
    assert parse_method("ebd+ebf=a.ckpt,b.ckpt") == ("ebd+ebf", {"checkpoints": ["a.ckpt", "b.ckpt"]})
    assert parse_method("ebd+ebf=a.ckpt,b.ckpt:mode=windowed") == (
        "ebd+ebf",
        {"mode": "windowed", "checkpoints": ["a.ckpt", "b.ckpt"]},
    )
    with pytest.raises(KeyError, match="unknown method 'nope'"):
        build_method("nope")


def _reported_figure(clips, sigmas, corruption="angular-0.5") -> float:
    """The harness's figure on the tuning inputs: mean over clips of each clip's RMS angle error."""
    from mocapnet.evaluate.metrics import angle_err_deg

    errs = []
    for m in clips:
        noisy, mask = corrupt_motion(m, corruption, np.random.default_rng(seed_for("", m.name, -1, corruption)))
        out = gaussian_smooth(lerp_fill(noisy, mask), sigmas, m.fps)
        errs.append(angle_err_deg(out, m.channels, m.skeleton.scored_mask))
    return float(np.mean(errs))


def test_gaussian_tuned_minimises_the_reported_figure(cmu):
    """Clips of very different lengths: the long one would dominate summed squared error; the tuned σ must do
    at least as well on the reported figure (mean of per-clip RMS) as every single σ and as the σ chosen by
    summed squared error."""
    from mocapnet.methods.baselines import SIGMA_GRID_S

    bounds = [(0, 1500), (1500, 1560), (1600, 1660), (1700, 1760), (1800, 1860), (1900, 1960)]
    clips = [Motion(cmu.skeleton, cmu.channels[a:b], cmu.fps, f"c{a}") for a, b in bounds]
    tuned = _reported_figure(clips, tune_sigmas(clips, "angular-0.5"))
    for sigma in SIGMA_GRID_S:
        assert tuned <= _reported_figure(clips, sigma) + 1e-12, sigma
    scored = cmu.skeleton.scored_mask
    sse = np.zeros((len(SIGMA_GRID_S), scored.size))
    for m in clips:
        noisy, mask = corrupt_motion(m, "angular-0.5", np.random.default_rng(seed_for("", m.name, -1, "angular-0.5")))
        for g, sigma in enumerate(SIGMA_GRID_S):
            sse[g] += ((gaussian_smooth(lerp_fill(noisy, mask), sigma, m.fps) - m.channels) ** 2).sum(axis=0)
    by_sse = np.asarray(SIGMA_GRID_S)[np.argmin(sse, axis=0)]
    assert tuned < _reported_figure(clips, by_sse)


def test_method_spec_parses_once_with_windows_paths():
    from mocapnet.methods.registry import MethodSpec

    spec = MethodSpec.parse("ebf=C:/runs/x.ckpt")
    assert (spec.name, spec.checkpoints, dict(spec.options)) == ("ebf", ("C:/runs/x.ckpt",), {})
    spec = MethodSpec.parse(r"ebd+ebf=C:\runs\d.ckpt,D:/f.ckpt:mode=windowed")
    assert spec.checkpoints == (r"C:\runs\d.ckpt", "D:/f.ckpt") and dict(spec.options) == {"mode": "windowed"}
    assert str(spec) == r"ebd+ebf=C:\runs\d.ckpt,D:/f.ckpt:mode=windowed"  # as written
    assert MethodSpec.parse(spec) is spec
    assert MethodSpec.parse("knn:k=8").with_options(database="/db").canonical() == "knn:k=8,database=/db"
    assert MethodSpec.parse("ebf").with_checkpoints(["a.ckpt"]).canonical() == "ebf=a.ckpt"
    assert build_method(MethodSpec.parse("lerp")).name == "lerp"
    with pytest.raises(ValueError, match="no method name"):
        MethodSpec.parse(":k=1")
    with pytest.raises(ValueError, match="must be key=value"):
        MethodSpec.parse("knn:k")


def test_gaussian_tuned_can_tune_on_another_corpus(shared):
    method = build_method("gaussian-tuned:tune_on=bandai2,max_clips=20", MethodContext(corruption="angular-0.5"))
    sigmas = method.clean.sigmas_s
    assert sigmas.shape == (132,) and (sigmas > 0).any()


def test_every_registered_method_is_found_without_importing_its_module_first():
    """Each method name is in the registry's lazy table (a fresh process can build it by name alone), and
    every module that registers it is listed."""
    from mocapnet.methods.registry import _LAZY, _modules, available

    entries = available()
    missing = sorted({e.name for e in entries} - set(_LAZY))
    assert not missing, f"add to registry._LAZY: {missing}"
    for e in entries:
        assert e.factory.__module__ in _modules(e.name), (e.name, e.space, e.factory.__module__)


def test_limit_change_with_an_anchor_caps_the_distance_from_it():
    """``anchor``: each channel ends within ``factor`` x the input's noise (RMS) of the anchor, on the line from the
    anchor to the cleaned output; channels already that close are left as cleaned."""
    from mocapnet.selfcheck import limit_change, noise_level

    rng = np.random.default_rng(0)
    noisy = np.cumsum(rng.normal(0, 0.5, (400, 3)), axis=0) + rng.normal(0, 2.0, (400, 3))
    anchor = noisy + 0.1
    cleaned = anchor + np.array([0.1, 5.0, 20.0])  # channel 0 close to the anchor, 1 and 2 far
    out = limit_change(noisy, cleaned, 1.0, anchor=anchor)
    cap = noise_level(noisy)
    np.testing.assert_allclose(out[:, 0], cleaned[:, 0])
    np.testing.assert_allclose(np.sqrt(((out - anchor)[:, 1:] ** 2).mean(0)), cap[1:])
    np.testing.assert_array_equal(limit_change(noisy, cleaned, 1.0), limit_change(noisy, cleaned, 1.0, anchor=noisy))


def test_noise_level_of_higher_order_ignores_slow_polynomials_and_finds_white_noise():
    """Differences of order n cancel a polynomial of degree < n: a cubic shows no noise at order 4 and much at
    order 2; white noise of std 2 reads about 2 at every order; order 2 is the default; other orders refused."""
    from mocapnet.selfcheck import NOISE_ORDERS, limit_change, noise_level

    t = np.arange(600.0)[:, None]
    cubic = 1e-5 * (t - 300.0) ** 3 * np.array([1.0, -2.0])
    assert (noise_level(cubic, 4) < 1e-6).all() and (noise_level(cubic, 2) > 1e-3).all()
    white = np.random.default_rng(0).normal(0.0, 2.0, (20000, 2))
    for order in NOISE_ORDERS:
        np.testing.assert_allclose(noise_level(white, order), 2.0, rtol=0.05)
    np.testing.assert_array_equal(noise_level(white), noise_level(white, 2))
    assert (noise_level(white[:4], 4) == 0).all()
    cleaned = white * 0.0
    np.testing.assert_array_equal(limit_change(white, cleaned, 1.0), limit_change(white, cleaned, 1.0, order=2))
    with pytest.raises(ValueError, match="noise order"):
        noise_level(white, 5)
