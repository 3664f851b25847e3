import numpy as np
import pytest

from chirplidar.config import load_mission
from chirplidar.waveform import ChirpTrain, mls
from conftest import BENCH


def _train(**over):
    cfg = load_mission(BENCH, over)
    return ChirpTrain.from_config(cfg)


def test_instantaneous_frequency_is_linear():
    # eq. 3.2.3: f(t) = F1 + (F2 - F1) t / tau over the rising ramp.
    tr = _train()
    tc = np.linspace(1e-6, tr.rise_s - 1e-6, 50)
    dt = 1e-12
    dphi = np.unwrap(np.stack([tr.phase(tc - dt), tr.phase(tc + dt)]), axis=0)
    f = (dphi[1] - dphi[0]) / (2 * np.pi * 2 * dt)
    np.testing.assert_allclose(f, 100e6 + 200e6 * tc / 40e-6, rtol=1e-6)


def test_sample_and_hold_holds_the_frequency():
    tr = _train(**{"chrp.qnt": 1e-6})
    tc = np.array([2.2e-6, 2.8e-6])  # same hold interval [2, 3) us
    dt = 1e-12
    f = [np.angle(np.exp(1j * (tr.phase(t + dt) - tr.phase(t - dt)))) / (4 * np.pi * dt) for t in tc]
    np.testing.assert_allclose(f, 100e6 + 5e12 * 2e-6, rtol=1e-6)


def test_envelope_rise_hold_fall():
    tr = _train()
    w = tr.envelope(np.array([0.0, 1e-6, 2e-6, 20e-6, 39e-6, 41e-6, 60e-6]))
    assert w[0] == 0 and w[2] == 1.0 and w[3] == 1.0 and 0 < w[1] < 1 and 0 < w[4] < 1
    assert w[5] == 0 and w[6] == 0  # the falling ramp carries no amplitude


@pytest.mark.parametrize("order", [3, 7, 10, 13])
def test_mls_is_maximal_length(order):
    c = mls(order).astype(float)
    n = 2**order - 1
    assert c.size == n and c.sum() == -1  # one more -1 than +1 (balance property)
    # Two-valued periodic autocorrelation: n at zero lag, -1 elsewhere.
    ac = np.fft.ifft(np.abs(np.fft.fft(c)) ** 2).real
    np.testing.assert_allclose(ac[0], n)
    np.testing.assert_allclose(ac[1:], -1.0, atol=1e-6)
