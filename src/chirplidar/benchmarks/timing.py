"""Timing of the simulator against a reference cost (DESIGN rule 1: show what accuracy costs in
time).

``bench_shot`` times one rf-tier shot of the thesis bench mission against ONE real FFT of the same
record length (N = sims.T * sims.Fs samples), the floor any time-domain simulation pays. Times are
wall-clock seconds (``time.perf_counter``), the median of ``repeats`` runs after one warm-up run.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import scipy.fft

from ..mission_files import default_mission_path


def time_call(fn: Callable[[], Any], repeats: int = 5, warmup: int = 1) -> float:
    """Median wall-clock time of ``fn()`` in seconds over ``repeats`` calls, after ``warmup``
    calls."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def record_samples(cfg) -> int:
    """Samples in one simulated record: N = round(sims.T * sims.Fs)."""
    return int(round(cfg.simulation.duration_s * cfg.simulation.sample_rate_hz))


def bench_shot(mission: str | Path | None = None, overrides: list[str] | None = None,
               repeats: int = 5, seed: int = 0, tier: str = "rf") -> dict[str, float | int]:
    """Time one shot of ``mission`` (default: missions/thesis_bench.toml, homodyne) against one FFT.

    Returns ``rf_shot_s`` (s per shot), ``fft_s`` (s per FFT of the same length), ``ratio``
    (shot / FFT) and ``n_samples``. Shots and FFTs are timed in alternating pairs and ``ratio`` is
    the median of the per-pair ratios: a shared machine's speed drifts between seconds, and a ratio
    of two medians taken apart would carry that drift. Absolute times are not asserted anywhere.
    """
    from ..api import simulate_shot
    from ..config import load_mission

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    cfg = load_mission(mission if mission is not None else default_mission_path(), overrides or [])
    n = record_samples(cfg)
    record = np.random.default_rng(seed).standard_normal(n)
    shot = lambda: simulate_shot(cfg, seed=seed, tier=tier)  # noqa: E731
    fft = lambda: scipy.fft.rfft(record)  # noqa: E731
    shot(), fft()  # warm-up: caches, FFT plans
    shots, ffts = [], []
    for _ in range(repeats):
        shots.append(time_call(shot, repeats=1, warmup=0))
        # The FFT is ~1 ms: the median of a few gives a steady reading next to each shot.
        ffts.append(time_call(fft, repeats=5, warmup=0))
    ratios = [a / b for a, b in zip(shots, ffts)]
    return {"rf_shot_s": statistics.median(shots), "fft_s": statistics.median(ffts),
            "ratio": statistics.median(ratios), "n_samples": n}


def bench_tiers(mission: str | Path | None = None, overrides: list[str] | None = None,
                repeats: int = 5, seed: int = 0, baseband_batch: int = 256,
                link_batch: int = 1_000_000) -> dict[str, float]:
    """Seconds per shot of the three tiers on one mission (default: the thesis bench, homodyne).

    rf: one shot per call (as :func:`bench_shot`); baseband: a batch of ``baseband_batch`` shots
    per call; link: a batch of ``link_batch`` shots per call; each per-shot time is the call's time
    over its shots. The tiers are timed in turn for ``repeats`` rounds after one warm-up call each
    and each key is the median over the rounds (a shared machine's drift affects them alike).
    Returns ``rf_shot_s``, ``baseband_shot_s``, ``link_shot_s``, ``baseband_speedup``
    (rf_shot_s / baseband_shot_s) and ``link_shots_per_s``.
    """
    from ..channel.lab import simulate_lab
    from ..config import load_mission

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    for name, value in (("baseband_batch", baseband_batch), ("link_batch", link_batch)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    cfg = load_mission(mission if mission is not None else default_mission_path(), overrides or [])
    calls = {
        "rf": (lambda: simulate_lab(cfg, "rf", np.random.default_rng(seed)), 1),
        "baseband": (lambda: simulate_lab(cfg, "baseband", np.random.default_rng(seed),
                                          batch=int(baseband_batch)), int(baseband_batch)),
        "link": (lambda: simulate_lab(cfg, "link", np.random.default_rng(seed),
                                      batch=int(link_batch)), int(link_batch)),
    }
    for fn, _ in calls.values():
        fn()  # warm-up: caches, FFT plans
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, (fn, shots) in calls.items():
            times[name].append(time_call(fn, repeats=1, warmup=0) / shots)
    rf, bb, link = (statistics.median(times[k]) for k in ("rf", "baseband", "link"))
    return {"rf_shot_s": rf, "baseband_shot_s": bb, "link_shot_s": link,
            "baseband_speedup": rf / bb, "link_shots_per_s": 1.0 / link}


# Settings that switch each effect on for timing (a representative case of each).
EFFECT_SETTINGS: dict[str, list[str]] = {
    "phase_noise": ["lsr.Lw=1e4"],
    "speckle": ["effects.speckle.cells=1"],
    "doppler": ["effects.doppler.radial_velocity_mps=1.0"],
    # Field-trial-like 8" telescope at f/5 with a 30 % obstruction, SMF-28 at 1310 nm (4.6 um).
    "coupling": ["atm.state=on", "effects.coupling.obstruction_ratio=0.3",
                 "effects.coupling.focal_length_m=1.0",
                 "effects.coupling.mode_field_radius_m=4.6e-6",
                 "effects.coupling.fiber_numerical_aperture=0.14",
                 'effects.coupling.target="diffuse"'],
}
# Turbulence degrades the coupling, so it is timed with 'coupling' on too (mean fading: the mode
# mission runs use).
EFFECT_SETTINGS["turbulence"] = EFFECT_SETTINGS["coupling"] + [
    'effects.turbulence.fading="mean"', "effects.turbulence.outer_scale_m=20"]
EFFECTS_ALSO_ENABLED = {"turbulence": ["coupling"]}


def bench_effects(mission: str | Path | None = None, overrides: list[str] | None = None,
                  repeats: int = 11, seed: int = 0, tier: str = "rf") -> dict[str, float]:
    """Seconds per shot with no effect and with each registered effect on alone.

    Keys: ``none_s`` and ``<effect>_s`` for every effect of the registry; shots of all settings
    are timed in turn, ``repeats`` rounds, and each key is the median over its rounds (so drift of
    a shared machine affects them alike).
    """
    import json

    from ..api import simulate_shot
    from ..channel.effects import EFFECTS
    from ..config import load_mission

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    path = mission if mission is not None else default_mission_path()
    configs = {"none": load_mission(path, overrides or [])}
    for name in EFFECTS:
        names = EFFECTS_ALSO_ENABLED.get(name, []) + [name]
        extra = EFFECT_SETTINGS[name] + [f"effects.enabled={json.dumps(names)}"]
        configs[name] = load_mission(path, (overrides or []) + extra)
    times: dict[str, list[float]] = {name: [] for name in configs}
    for cfg in configs.values():
        simulate_shot(cfg, seed=seed, tier=tier)  # warm-up: caches
    for _ in range(repeats):
        for name, cfg in configs.items():
            times[name].append(time_call(lambda: simulate_shot(cfg, seed=seed, tier=tier),
                                         repeats=1, warmup=0))
    return {f"{name}_s": statistics.median(t) for name, t in times.items()}
