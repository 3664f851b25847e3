"""Plots: beat spectrum, sweep and sensitivity figures on synthetic inputs (no simulation)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

from chirplidar.viz.sensitivity import plot_sensitivity, plot_sweep
from chirplidar.viz.spectrum import plot_beat_spectrum, zoom_span_hz

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def is_png(path) -> bool:
    return path.is_file() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_MAGIC


def synthetic_spectrum(f_peak_hz=22e6, snr_db=30.0, n=96001, fs=3e9, seed=0) -> dict:
    """Exponential noise at 1e-17 W/Hz plus a sinc^2 line; first bin exactly zero (DC removed)."""
    rng = np.random.default_rng(seed)
    f = np.linspace(0.0, fs / 2, n)
    df = f[1]
    noise = 1e-17
    psd = noise * rng.exponential(size=n) + noise * 10 ** (snr_db / 10) * np.sinc((f - f_peak_hz) / df) ** 2
    psd[0] = 0.0
    return {"f_hz": f, "psd_w_per_hz": psd, "f_peak_hz": f_peak_hz,
            "f_lo_hz": f_peak_hz - 0.44 * df, "f_hi_hz": f_peak_hz + 0.44 * df,
            "noise_psd_w_per_hz": noise, "rbw_hz": 30e3}


@pytest.mark.parametrize("unit", ["dBm", "dBm/Hz"])
def test_beat_spectrum_png(tmp_path, unit):
    out = plot_beat_spectrum(synthetic_spectrum(), tmp_path / "sub" / "s.png", unit=unit,
                             outputs={"SNR": 30.0, "d_rx": 1572.3, "Psig": -math.inf})
    assert is_png(out)


def test_beat_spectrum_without_peak_or_power(tmp_path):
    spec = synthetic_spectrum()
    spec.update(f_peak_hz=math.nan, f_lo_hz=math.nan, f_hi_hz=math.nan)
    spec["psd_w_per_hz"] = np.zeros_like(spec["f_hz"])      # zero power: dB is -inf everywhere
    assert is_png(plot_beat_spectrum(spec, tmp_path / "empty.png"))


def test_beat_spectrum_rejects_bad_input(tmp_path):
    spec = synthetic_spectrum(n=101)
    with pytest.raises(ValueError, match="unit"):
        plot_beat_spectrum(spec, tmp_path / "x.png", unit="W")
    spec["psd_w_per_hz"] = spec["psd_w_per_hz"][:-1]
    with pytest.raises(ValueError, match="same length"):
        plot_beat_spectrum(spec, tmp_path / "x.png")


def test_zoom_span_contains_peak_and_stays_in_range():
    spec = synthetic_spectrum(f_peak_hz=0.2e6)
    lo, hi = zoom_span_hz(spec)
    assert lo == 0.0 and 0.2e6 < hi < 5e6
    spec = synthetic_spectrum()
    lo, hi = zoom_span_hz(spec)
    assert lo < 22e6 < hi and hi - lo >= 2 * 40 * 30e3
    spec["f_peak_hz"] = math.nan
    assert zoom_span_hz(spec) is None


def sweep_dataset(n=6, repeat=3, scale="lin") -> xr.Dataset:
    x = np.linspace(20.0, 110.0, n) if scale == "lin" else np.geomspace(1.0, 100.0, n)
    psig = -8.0 - np.repeat(x[:, None], repeat, axis=1)
    snr = psig + 106.0 + np.random.default_rng(1).normal(0, 0.5, psig.shape)
    psig[-1, 0] = -math.inf                                  # a zero-power shot
    snr[-1, :] = -math.inf
    return xr.Dataset(
        {"Psig": (("x", "repeat"), psig, {"units": "dBm", "long_name": "received power"}),
         "SNR": (("x", "repeat"), snr, {"units": "dB", "long_name": "signal to noise ratio"})},
        coords={"x": ("x", x, {"long_name": "atm.Pattn"})},
        attrs={"vary": "atm.Pattn", "tier": "link", "seed": 1, "scale": scale})


def test_sweep_plot_with_repeats_and_minus_inf(tmp_path):
    assert is_png(plot_sweep(sweep_dataset(), tmp_path / "a.png"))
    assert is_png(plot_sweep(sweep_dataset(repeat=1, scale="log"), tmp_path / "b.png",
                             x="x", y="Psig"))
    assert is_png(plot_sweep(sweep_dataset(), tmp_path / "c.png", x="atm.Pattn", y="SNR"))


def test_sweep_plot_unknown_name(tmp_path):
    with pytest.raises(KeyError, match="valid names"):
        plot_sweep(sweep_dataset(), tmp_path / "d.png", y="Crx")


def test_sensitivity_plot(tmp_path):
    from chirplidar.thesis_sensitivity import load_measured, shot_noise_snr_db

    p = np.linspace(-40.0, -105.0, 14)
    sim = {"homodyne": (p, p + 106.0), "direct": (p + 20, 2 * (p + 65.0)),
           "heterodyne": (np.append(p, -math.inf), np.append(p + 80.0, -math.inf))}
    line = np.linspace(-115, -10, 50)
    out = plot_sensitivity(tmp_path / "fig.png", sim, load_measured(),
                           shot_noise=(line, shot_noise_snr_db(line)))
    assert is_png(out)


def test_physics_and_cli_do_not_import_matplotlib():
    code = ("import sys, chirplidar.config, chirplidar.cli, chirplidar.thesis_sensitivity\n"
            "import chirplidar.benchmarks.timing\n"
            "try:\n    import chirplidar.api\nexcept ImportError:\n    pass\n"
            "bad = [m for m in sys.modules if m.startswith('matplotlib')]\n"
            "assert not bad, bad\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
