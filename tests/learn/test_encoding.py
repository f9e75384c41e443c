import numpy as np
import pytest

from forcdecode.learn.encoding import encode, readout


@pytest.mark.parametrize("method", ["parabola", "softmax"])
def test_round_trip_is_exact_for_a_perfect_output(method):
    u = np.linspace(0, 1, 1001)
    tolerance = 1e-9 if method == "parabola" else None
    recovered = readout(encode(u), method)
    if method == "parabola":
        np.testing.assert_allclose(recovered, u, atol=tolerance)
    else:  # softmax of a width-1 log-Gaussian: exact in the interior, biased near the edges
        inner = (u > 0.3) & (u < 0.7)
        np.testing.assert_allclose(recovered[inner], u[inner], atol=1e-3)


def test_target_shape_and_peak():
    t = encode(np.array([[0.0, 0.37]]))
    assert t.shape == (1, 2, 11)
    assert t[0, 0, 0] == 20.0 and np.argmax(t[0, 1]) == 4


def test_guard_on_flat_or_convex_outputs():
    flat = np.zeros((1, 11))
    convex = (np.arange(11) - 5.0) ** 2  # a minimum, not a peak
    for outputs in (flat, convex[None, :]):
        u = readout(outputs)
        assert np.all(np.isfinite(u)) and np.all((u >= 0) & (u <= 1))
    # flat: the 5-node weighted mean around the clamped argmax (node 2) -> y = 2
    assert readout(flat)[0] == pytest.approx(0.2)


def test_noise_robustness_of_both_readouts():
    rng = np.random.default_rng(0)
    u = rng.random(4000)
    noisy = encode(u) + rng.normal(0, 0.5, size=(4000, 11))
    for method in ("parabola", "softmax"):
        error = np.abs(readout(noisy, method) - u)
        assert np.median(error) < 0.05, method


def test_wrong_width_is_an_error():
    with pytest.raises(ValueError, match="11"):
        readout(np.zeros((2, 10)))


def test_peak_height_carries_the_variance():
    """MSE-optimal outputs are E[t_k] = 20 − (k − μ)²/2 − v/2: the readout recovers μ and v."""
    from forcdecode.learn.encoding import readout_with_variance

    rng = np.random.default_rng(0)
    for mu, sd in ((0.53, 0.08), (0.3, 0.03), (0.7, 0.12)):
        u = np.clip(rng.normal(mu, sd, 400_000), 0, 1)
        expected_outputs = encode(u).mean(axis=0)
        mean, variance = readout_with_variance(expected_outputs[None])
        assert mean[0] == pytest.approx(u.mean(), abs=2e-3)
        assert variance[0] == pytest.approx(u.var(), rel=0.03)
    _, exact = readout_with_variance(encode(np.array([0.42])))
    assert exact[0] == pytest.approx(0.0, abs=1e-12)
