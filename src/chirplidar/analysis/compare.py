"""One mission, several instruments, side by side (``chirplidar compare``; thesis Ch. 2).

Each instrument file is flown over the same mission (same path, scene, beams, span and seed:
``--set instrument=FILE``, :func:`chirplidar.config.loader.with_instrument`), each at its own
shot rate and through its own tier (a pulsed altimeter through the pulsed tier, a chirped lidar
through the mission's tier or the link tier). From each run's results file:

* detection probability: detected shots / shots that reached a surface;
* median SNR of those shots (dB; the chirped tiers' SNR in the resolution bandwidth, the pulsed
  tier's over its received pulse: each tier's own definition);
* range precision (1.4826 x the median absolute deviation of the range error, robust to the
  odd false alarm) and bias (the median range error, true - measured) of the detected shots;
* footprint diameter (median) and coverage (share of ``cell_m`` cells of the survey region with a
  detected shot, :func:`chirplidar.analysis.coverage.compute_coverage`).

From the instrument itself: mean and peak transmitted optical power, the energy of one pulse
(a chirped lidar: of one chirp ramp), the electrical bandwidth its receiver needs (pulsed: the
detector's; a self-chirped coherent receiver: the highest beat it saw; direct detection of a
chirp: the chirp's top frequency, dechirped after the photodiode) and its sensitivity: the
received signal power at which half the shots are detected, from a sweep of the received power
through the instrument's tier on a point target at the run's median range (:func:`power_sweep`;
the received power of a pulsed instrument is its pulse's peak, of a chirped one the mean during
the record). The sweep also gives the figure: range precision and detection
probability against received power.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The table's rows: (key, label, unit). Keys are those of :attr:`InstrumentResult.row`.
ROWS: tuple[tuple[str, str, str], ...] = (
    ("kind", "instrument kind", ""),
    ("tier", "tier", ""),
    ("shot_rate_hz", "shot rate", "Hz"),
    ("mean_power_w", "mean optical power", "W"),
    ("peak_power_w", "peak optical power", "W"),
    ("pulse_energy_j", "energy per pulse (chirp)", "J"),
    ("bandwidth_hz", "receiver bandwidth needed", "Hz"),
    ("sensitivity_dbm", "sensitivity (50 % detected)", "dBm"),
    ("median_received_dbm", "median received power", "dBm"),
    ("detection_probability", "detection probability", ""),
    ("median_snr_db", "median SNR", "dB"),
    ("range_precision_m", "range precision", "m"),
    ("range_bias_m", "range bias", "m"),
    ("footprint_m", "footprint diameter", "m"),
    ("coverage", "coverage", ""),
)
#: Shots per received-power level of the sweep, by tier (the rf tier is the expensive one).
SWEEP_SHOTS = {"link": 400, "pulsed": 400, "baseband": 32, "rf": 4}
#: The sweep's received-power levels: this many, over this span (dB) around the sensitivity,
#: found first on a coarse grid of COARSE_STEP_DB over COARSE_SPAN_DB around the run's median.
SWEEP_LEVELS = 25
SWEEP_SPAN_DB = (-20.0, 40.0)
COARSE_STEP_DB = 5.0
COARSE_SPAN_DB = (-160.0, 60.0)
#: Robust standard deviation of a normal sample from its median absolute deviation.
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class PowerSweep:
    """Received power (dBm), detection probability, range precision (m) at each level."""

    received_dbm: np.ndarray
    detection_probability: np.ndarray
    range_precision_m: np.ndarray


@dataclass
class InstrumentResult:
    """One instrument's run: its file, its label, its table column and its sweep."""

    instrument: Path
    label: str
    results: Path
    row: dict = field(default_factory=dict)
    sweep: PowerSweep | None = None


def robust_std(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (the std of a normal sample); NaN if empty."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def _median(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else float("nan")


def results_row(path: Path, cell_m: float) -> dict:
    """The run's rows of the table (module docstring) from its results file."""
    from ..mission.results import read_netcdf
    from .coverage import compute_coverage
    from .coverage_files import CoverageError

    ds = read_netcdf(path)
    det = ds["detected"].values
    surface = det != 2
    hit = det == 1
    err = ds["range_error"].values[hit]
    with np.errstate(divide="ignore"):
        p_dbm = 10.0 * np.log10(ds["received_power"].values[surface] / 1e-3)
    row = {
        "detection_probability": float(hit.sum() / surface.sum()) if surface.any() else np.nan,
        "median_snr_db": _median(ds["snr_db"].values[surface]),
        "median_received_dbm": _median(p_dbm),
        "range_precision_m": robust_std(err),
        "range_bias_m": _median(err),
        "footprint_m": _median(ds["footprint_diameter"].values[surface]),
        "max_beat_hz": (float(np.nanpercentile(ds["beat_frequency"].values[hit], 99))
                        if hit.any() and np.isfinite(ds["beat_frequency"].values[hit]).any()
                        else np.nan),
    }
    try:
        row["coverage"] = compute_coverage([path], cell_m=cell_m).summary["fraction_covered"]
    except CoverageError:   # no detected shot: nothing covered
        row["coverage"] = 0.0
    return row


def instrument_row(config) -> dict:
    """The instrument's own rows: shot rate, transmitted powers, pulse energy, bandwidth."""
    if config.kind == "pulsed":
        from ..waveform.pulse import peak_power_per_joule

        p = config.pulse
        return {"kind": "pulsed", "shot_rate_hz": p.prf_hz, "mean_power_w": p.energy_j * p.prf_hz,
                "peak_power_w": p.energy_j * peak_power_per_joule(p.shape, p.duration_s),
                "pulse_energy_j": p.energy_j,
                "bandwidth_hz": config.pulse_receiver.bandwidth_hz}
    from ..channel.lab import lab_budget
    from ..transmitter.mzm import mzm_peak_power_transmission

    bud = lab_budget(config)
    peak = (bud.ptx_w / bud.mzm_mean_transmission
            * mzm_peak_power_transmission(bud.train, config.modulator.bias_v,
                                          config.modulator.v_pi_v))
    return {"kind": "chirped", "shot_rate_hz": config.survey.prf_hz, "mean_power_w": bud.ptx_w,
            "peak_power_w": peak, "pulse_energy_j": bud.ptx_w * bud.train.rise_s}


def chirped_bandwidth_hz(config, max_beat_hz: float) -> float:
    """The electrical bandwidth a chirped receiver needs: a self-chirped coherent receiver its
    highest beat; direct detection the chirp's top frequency (its photocurrent carries the whole
    chirp, dechirped in RF after the photodiode; thesis Sec. 2.1, the KU hybrid radar);
    heterodyne the LO offset plus the chirp's top."""
    w = config.waveform
    top = w.f_stop_hz + w.f_offset_hz
    if config.system.receiver in ("pin", "apd"):
        return float(top)
    if config.system.coherent_mode == "heterodyne":
        return float(config.balanced.lo_offset_hz + top)
    return float(max_beat_hz)


def power_sweep(config, range_m: float, median_dbm: float, seed: int) -> PowerSweep:
    """Detection probability and range precision against received signal power, through the
    configuration's survey tier on a point target at ``range_m`` (module docstring): a coarse
    pass of few shots finds where half the shots are detected, the sweep spans
    :data:`SWEEP_SPAN_DB` around it."""
    coarse = median_dbm + np.arange(COARSE_SPAN_DB[0], COARSE_SPAN_DB[1] + 1e-9, COARSE_STEP_DB)
    found = sensitivity_dbm(_sweep_levels(config, range_m, coarse, seed, shots=32))
    centre = found if np.isfinite(found) else median_dbm
    return _sweep_levels(config, range_m, centre + np.linspace(*SWEEP_SPAN_DB, SWEEP_LEVELS),
                         seed)


def _sweep_levels(config, range_m: float, levels, seed: int, shots: int | None = None):
    """:class:`PowerSweep` at the received powers ``levels`` (dBm)."""
    from ..config.instrument import instrument_from_config
    from ..mission.measure import survey_returns
    from ..tiers.registry import TIERS
    from ..units import db_to_ratio
    from ..waveform.pulse import peak_power_per_joule

    instrument = instrument_from_config(config)
    tier = config.survey.tier
    shots = SWEEP_SHOTS[tier] if shots is None else min(shots, SWEEP_SHOTS[tier])
    p_det, precision = np.empty(levels.size), np.empty(levels.size)
    threshold = config.survey.detection_threshold_db
    for k, dbm in enumerate(levels):
        watts = 1e-3 * float(db_to_ratio(dbm))
        if config.kind == "pulsed":   # the pulse's peak power (the pulsed tier's Psig)
            p = config.pulse
            transmission = watts / (p.energy_j * peak_power_per_joule(p.shape, p.duration_s))
        else:
            from ..channel.lab import lab_budget

            transmission = watts / lab_budget(config).ptx_w
        returns = survey_returns(config, range_m, transmission, shots)
        out = TIERS[tier].simulate(instrument, returns,
                                   np.random.default_rng([seed, k]))
        if config.kind == "pulsed":
            seen = np.asarray(out["detected"], bool)
        else:
            seen = (out["SNR"] >= threshold) & np.isfinite(out["d_rx"])
        p_det[k] = seen.mean()
        err = np.asarray(out["d_error"])[seen]
        precision[k] = robust_std(err) if err.size >= 5 else np.nan
    return PowerSweep(levels, p_det, precision)


def sensitivity_dbm(sweep: PowerSweep, level: float = 0.5) -> float:
    """The lowest received power at which the detection probability reaches ``level``
    (linear interpolation between sweep levels), NaN if it never does or already does at the
    sweep's lowest level (the sweep did not bracket it)."""
    p = sweep.detection_probability
    above = np.flatnonzero(p >= level)
    if above.size == 0 or above[0] == 0:
        return float("nan")
    k = int(above[0])
    x0, x1 = sweep.received_dbm[k - 1], sweep.received_dbm[k]
    return float(x0 + (level - p[k - 1]) * (x1 - x0) / (p[k] - p[k - 1]))


def compare_instruments(mission, instruments, *, out_dir, overrides=(), span_s=None,
                        seed=None, cell_m: float = 50.0, progress=False,
                        sweep: bool = True) -> list[InstrumentResult]:
    """Fly ``mission`` with each instrument file and tabulate them (module docstring). Each run
    writes ``out_dir/<mission>_<instrument>.nc`` (replacing an earlier comparison's)."""
    from ..mission.runner import run_mission

    # every instrument's flight checked (prepared as `run` prepares it) before any flies
    flights = [(Path(p).resolve(), *_prepared_flight(mission, p, overrides, span_s, seed))
               for p in instruments]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for path, sets, config in flights:
        out = out_dir / f"{Path(mission).stem}_{path.stem}.nc"
        run = run_mission(mission, overrides=sets, out=out, seed=seed, overwrite=True,
                          progress=progress)
        item = InstrumentResult(path, path.stem, run.path)
        item.row = {"tier": config.survey.tier, **instrument_row(config),
                    **results_row(run.path, cell_m)}
        if config.kind == "chirped":
            item.row["bandwidth_hz"] = chirped_bandwidth_hz(config, item.row["max_beat_hz"])
        if sweep:
            item.sweep = _sweep_for(config, run.path, item.row["median_received_dbm"])
            item.row["sensitivity_dbm"] = sensitivity_dbm(item.sweep)
        results.append(item)
    return results


def _prepared_flight(mission, instrument, overrides, span_s, seed):
    """(the ``--set`` list that flies ``instrument`` over ``mission``, its span cut to
    ``span_s``; the configuration ``run`` prepares from it), checked as ``run`` checks a mission
    before any shot; ConfigError naming the instrument."""
    from ..config import ConfigError, load_mission
    from ..mission.preflight import prepare

    sets = [*overrides, f"instrument={Path(instrument).resolve()}"]
    try:
        if span_s is not None:
            start = load_mission(mission, sets).survey.start_s or 0.0
            sets.append(f"survey.stop_s={start + float(span_s)!r}")
        config = prepare(mission, overrides=sets, seed=seed)[0]
    except ConfigError as exc:
        raise ConfigError(f"--instrument {instrument}: {exc}") from None
    return sets, config


def _sweep_for(config, path: Path, median_dbm: float) -> PowerSweep:
    """The sweep of :func:`power_sweep` at the run's median range, its coarse pass around the
    run's median received power (1 km and -80 dBm when the run saw no surface)."""
    from ..mission.results import read_netcdf

    ds = read_netcdf(path)
    surface = ds["detected"].values != 2
    r = _median(ds["range_true"].values[surface])
    median = median_dbm if np.isfinite(median_dbm) else -80.0
    return power_sweep(config, r if np.isfinite(r) else 1e3, median, int(config.seed))


def format_table(results: list[InstrumentResult]) -> str:
    """The comparison as a text table: one row per quantity, one column per instrument."""
    head = ["quantity", *[r.label for r in results]]
    lines = []
    for key, label, unit in ROWS:
        cells = [f"{label}" + (f" [{unit}]" if unit else "")]
        for r in results:
            v = r.row.get(key, "")
            cells.append(v if isinstance(v, str) else _fmt(v))
        lines.append(cells)
    widths = [max(len(str(row[i])) for row in [head, *lines]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    return "\n".join(fmt.format(*row) for row in [head, *lines])


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{v:.4g}"
