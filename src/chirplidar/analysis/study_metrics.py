"""The metrics of one point of a mission study (:mod:`chirplidar.analysis.study`), read from its
results file chunk by chunk (:func:`point_metrics`).

"surface shots": shot-beams with a surface in the beam (``detected != 2``), detected or not.

==============================  =====  ===================================================
``detection_probability``       1      detected / surface shots
``median_snr_db``               dB     median of ``snr_db`` over the surface shots
``snr_p01_db``, ``snr_p10_db``  dB     1st and 10th percentiles of the same (fade depth)
``snr_p90_db``                  dB     90th percentile of the same
``median_received_power_dbm``   dBm    median of ``received_power`` in dBm (``units.power_dbm``)
``range_rms_m``                 m      sqrt(mean(range_error^2)) over the detected shots;
                                       NaN with none
``height_precision_m``          m      sample standard deviation (ddof 1, as ``chirplidar
                                       coverage``'s ``height_error_std``) of ``h_li -
                                       h_li_true`` over the detected shots; NaN below two
``fraction_covered``            1      with ``cell_m``: :mod:`chirplidar.analysis.coverage`
``flight_time_s``               s      last minus first shot time (``delta_time``) of the run
``shots``                       1      shot-beams of the run (trajectories x observations)
``detected_shots``              1      detected shot-beams of the run: what ``range_rms_m``
                                       and ``height_precision_m`` rest on (the table shows
                                       it; the plot marks points resting on fewer than 10)
``detection_threshold_db``      dB     the point's ``survey.detection_threshold_db``
                                       (NaN for a pulsed instrument: its threshold is
                                       in noise sigmas)
==============================  =====  ===================================================

A surface shot with no signal (zero received power; its ``snr_db`` is NaN in the results file,
"no value" since 10 log10(0) is not stored) counts as -inf dB in the SNR and power statistics, so
it pulls a median or percentile down instead of being dropped; a quantile that falls on (or
interpolates with) such a shot is -inf. No NaN, no warning. Quantiles are numpy's
(``np.percentile``, ``method="linear"``, for the 1st, 10th and 90th percentiles; ``np.median``, the
middle value or the mean of the middle two, for the medians), computed exactly: while the
surface shots' SNR and power fit in the memory budget (one results chunk, as
:func:`~chirplidar.mission.summary.summary_of_chunks` keeps) they are kept and the order
statistics taken with ``np.partition``; beyond it they come from
:func:`chirplidar.mission.summary.order_statistics` (a radix select over four more passes over the
file, memory bounded by one chunk whatever the run's length). Both give the same bits. Sums are
accumulated per chunk: the height spread with Chan et al.'s pairwise update of (n, mean, M2), the
range RMS from the sum of squares. A metric without shots to compute it from is NaN
(``range_rms_m`` when nothing is detected, ``height_precision_m`` with fewer than two detected
shots: one shot has no spread, and a standard deviation of 0 would read as a perfect
precision).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..config.loader import ConfigError
from ..mission.summary import quantile_between, quantile_ranks

#: The metrics of a point, in table order: name -> (units, long_name).
METRICS: dict[str, tuple[str, str]] = {
    "detection_probability": ("1", "detected shot-beams / shot-beams with a surface in the beam"),
    "median_snr_db": ("dB", ("median SNR in the RBW over the shot-beams with a surface in "
                             "the beam (zero signal counts as -inf dB)")),
    "snr_p01_db": ("dB", ("1st percentile of the SNR over the shot-beams with a surface in "
                          "the beam (deep fades)")),
    "snr_p10_db": ("dB", ("10th percentile of the SNR over the shot-beams with a surface in "
                          "the beam (fades)")),
    "snr_p90_db": ("dB", ("90th percentile of the SNR over the shot-beams with a surface in "
                          "the beam")),
    "median_received_power_dbm": ("dBm", ("median received optical signal power over the "
                                          "shot-beams with a surface in the beam (zero: -inf "
                                          "dBm)")),
    "range_rms_m": ("m", "RMS of range_error over the detected shot-beams"),
    "height_precision_m": ("m", ("sample standard deviation (ddof 1) of h_li - h_li_true "
                                 "over the detected shot-beams (NaN below two)")),
    "fraction_covered": ("1", "covered fraction of the region (chirplidar.analysis.coverage)"),
    "flight_time_s": ("s", "last minus first shot time of the run"),
    "shots": ("1", "shot-beams of the run"),
    "detected_shots": ("1", ("detected shot-beams of the run (what range_rms_m and "
                             "height_precision_m rest on)")),
    "detection_threshold_db": ("dB", ("SNR a return needs to count as detected "
                                      "(survey.detection_threshold_db)")),
}

#: Results variables a point's metrics read.
POINT_VARIABLES = ("detected", "snr_db", "received_power", "range_error", "h_li", "h_li_true",
                   "delta_time")

#: Metrics that are whole numbers (int64 in the dataset, int in the records).
COUNT_METRICS = ("shots", "detected_shots")

_DETECTED, _NO_SURFACE = 1, 2
#: Stands for -inf (zero signal) in the radix select, which takes finite values: below every
#: finite dB value a results file can hold.
_NEG_SENTINEL = -np.finfo(np.float64).max
_DEFAULT_OBS_BLOCK = 20000


def _obs_block(nc, default: int = _DEFAULT_OBS_BLOCK) -> int:
    """Observations per read: the results file's HDF5 chunk along ``obs`` (the run's
    ``survey.chunk_shots``), else ``default``."""
    try:
        chunks = nc["snr_db"].chunking()
    except (KeyError, IndexError, AttributeError):
        return default
    if isinstance(chunks, (list, tuple)) and len(chunks) == 2 and chunks[1] > 0:
        return int(chunks[1])
    return default


def _read_blocks(path, names=POINT_VARIABLES, obs_block: int | None = None):
    """Yield dicts of flattened 1-D arrays of ``names``, ``obs_block`` observations (all
    trajectories) at a time: memory bounded by one block whatever the file's length."""
    import netCDF4

    from ..mission.results import NETCDF_LOCK

    with NETCDF_LOCK:
        nc = netCDF4.Dataset(path)
    try:
        with NETCDF_LOCK:
            n_obs = len(nc.dimensions["obs"])
            step = int(obs_block) if obs_block else _obs_block(nc)
            variables = []
            for name in names:
                v = nc[name]
                v.set_auto_maskandscale(False)
                variables.append(v)
        for s0 in range(0, n_obs, step):
            with NETCDF_LOCK:
                block = {name: np.asarray(v[:, s0:s0 + step]).ravel()
                         for name, v in zip(names, variables)}
            yield block
    finally:
        with NETCDF_LOCK:
            nc.close()


def _snr_db(values) -> np.ndarray:
    """SNR in dB as stored, NaN (no signal) -> -inf."""
    x = np.asarray(values, dtype=np.float64)
    return np.where(np.isfinite(x), x, -np.inf)


def _power_dbm(values) -> np.ndarray:
    """Received power [W] in dBm (:func:`chirplidar.units.power_dbm`), zero or NaN -> -inf."""
    from ..units import power_dbm

    return np.atleast_1d(power_dbm(np.asarray(values, dtype=np.float64)))


def _lerp(a: float, b: float, g: float, *, median: bool = False) -> float:
    """:func:`~chirplidar.mission.summary.quantile_between` of the order statistics a <= b, or
    with ``median`` the mean of the middle two as ``np.median`` takes it; -inf (zero signal)
    when a is -inf."""
    if a == -math.inf:
        return -math.inf
    if median:
        return a if g == 0 else (a + b) / 2
    return quantile_between(a, b, g)


_QUANTILES = {"snr_p01_db": 0.01, "snr_p10_db": 0.10, "median_snr_db": 0.50, "snr_p90_db": 0.90}


class _PointPass:
    """The first pass over a point's results: counts, sums, time range and, while they fit
    in ``budget_bytes``, the surface shots' SNR and power (dB, -inf for none)."""

    def __init__(self, budget_bytes: int):
        self.budget_bytes = budget_bytes
        self.n_shots = self.n_surface = self.n_det = 0
        self.sq = 0.0                           # sum of range_error^2 (detected)
        self.h_n, self.h_mean, self.h_m2 = 0, 0.0, 0.0
        self.t_min, self.t_max = math.inf, -math.inf
        self.kept: list | None = []

    def add(self, block: dict) -> None:
        det = block["detected"]
        self.n_shots += det.size
        surface = det != _NO_SURFACE
        ok = det == _DETECTED
        self.n_surface += int(np.count_nonzero(surface))
        self.n_det += int(np.count_nonzero(ok))
        err = block["range_error"][ok].astype(np.float64)
        self.sq += float(np.sum(err * err))
        dh = (block["h_li"][ok] - block["h_li_true"][ok]).astype(np.float64)
        if dh.size:   # Chan, Golub & LeVeque (1979): combine (n, mean, M2) of two parts
            m_b = float(np.mean(dh))
            m2_b = float(np.sum((dh - m_b) ** 2))
            n = self.h_n + dh.size
            delta = m_b - self.h_mean
            self.h_mean += delta * dh.size / n
            self.h_m2 += m2_b + delta * delta * self.h_n * dh.size / n
            self.h_n = n
        t = block["delta_time"]
        if t.size:
            self.t_min = min(self.t_min, float(np.min(t)))
            self.t_max = max(self.t_max, float(np.max(t)))
        if self.kept is not None:
            self.kept.append(_surface_columns(block))
            if 16 * self.n_surface > self.budget_bytes:
                self.kept = None


def _surface_columns(block: dict) -> tuple[np.ndarray, np.ndarray]:
    """(SNR dB, received power dBm) of a block's surface shots, -inf for no signal."""
    surface = block["detected"] != _NO_SURFACE
    return _snr_db(block["snr_db"][surface]), _power_dbm(block["received_power"][surface])


def point_metrics(path, *, detection_threshold_db: float, cell_m: float | None = None,
                  budget_bytes: int | None = None, obs_block: int | None = None) -> dict:
    """The metrics of one run's results file (this module's docstring), read ``obs_block``
    observations at a time (default: the file's HDF5 chunk along ``obs``).

    ``budget_bytes``: memory for keeping the surface shots' SNR and power (16 bytes per shot)
    instead of selecting their quantiles in four more passes (default: one block of the read
    variables). ``cell_m``: also ``fraction_covered`` from :mod:`chirplidar.analysis.coverage`
    over the run's survey polygon (or the scene, when the file has none)."""
    path = Path(path)
    if obs_block is None:
        import netCDF4

        from ..mission.results import NETCDF_LOCK

        with NETCDF_LOCK, netCDF4.Dataset(path) as nc:
            obs_block = _obs_block(nc)
            n_traj = len(nc.dimensions["trajectory"])
    else:
        n_traj = 1
    if budget_bytes is None:
        budget_bytes = int(obs_block) * max(n_traj, 1) * 8 * len(POINT_VARIABLES)
    first = _PointPass(int(budget_bytes))
    for block in _read_blocks(path, obs_block=obs_block):
        first.add(block)
    nan = math.nan
    out = {name: nan for name in METRICS if name not in ("fraction_covered",)}
    n_s = first.n_surface
    out["shots"] = int(first.n_shots)
    out["detected_shots"] = int(first.n_det)
    out["detection_threshold_db"] = float(detection_threshold_db)
    out["flight_time_s"] = (first.t_max - first.t_min) if first.n_shots else nan
    out["detection_probability"] = first.n_det / n_s if n_s else nan
    if first.n_det:
        out["range_rms_m"] = math.sqrt(first.sq / first.n_det)
    if first.h_n >= 2:   # the sample standard deviation (ddof 1); one shot has no spread
        out["height_precision_m"] = math.sqrt(first.h_m2 / (first.h_n - 1))
    if n_s:
        snr_q = {name: quantile_ranks(n_s, q) for name, q in _QUANTILES.items()}
        pow_q = quantile_ranks(n_s, 0.5)
        snr_ranks = sorted({r for lo, hi, _ in snr_q.values() for r in (lo, hi)})
        pow_ranks = sorted({pow_q[0], pow_q[1]})
        if first.kept is not None:
            snr = np.concatenate([k[0] for k in first.kept])
            pw = np.concatenate([k[1] for k in first.kept])
            snr_at = dict(zip(snr_ranks, np.partition(snr, snr_ranks)[snr_ranks].tolist()))
            pow_at = dict(zip(pow_ranks, np.partition(pw, pow_ranks)[pow_ranks].tolist()))
        else:
            from ..mission.summary import order_statistics

            def blocks():
                for block in _read_blocks(path, names=("detected", "snr_db",
                                                       "received_power"),
                                          obs_block=obs_block):
                    snr_b, pw_b = _surface_columns(block)
                    yield (np.where(np.isfinite(snr_b), snr_b, _NEG_SENTINEL),
                           np.where(np.isfinite(pw_b), pw_b, _NEG_SENTINEL))

            s_vals, p_vals = order_statistics(blocks, [snr_ranks, pow_ranks])
            def back(v):
                return -math.inf if v == _NEG_SENTINEL else v

            snr_at = {r: back(v) for r, v in zip(snr_ranks, s_vals)}
            pow_at = {r: back(v) for r, v in zip(pow_ranks, p_vals)}
        for name, (lo, hi, g) in snr_q.items():
            out[name] = _lerp(snr_at[lo], snr_at[hi], g, median=name == "median_snr_db")
        out["median_received_power_dbm"] = _lerp(pow_at[pow_q[0]], pow_at[pow_q[1]], pow_q[2],
                                                 median=True)
    if cell_m is not None:
        # Nothing detected: no cell of the region holds a detection (the coverage module
        # refuses to grid a run without detections).
        out["fraction_covered"] = coverage_fraction(path, cell_m) if first.n_det else 0.0
    return out


def coverage_fraction(path, cell_m: float) -> float:
    """Covered fraction of a run: :func:`chirplidar.analysis.coverage.compute_coverage` on
    ``cell_m`` cells over the run's survey polygon (``region="survey"``) when the results file
    has one (``survey_polygon_wkt``), else over the scene (``region="scene"``)."""
    import netCDF4

    from ..mission.results import NETCDF_LOCK
    from .coverage import compute_coverage

    with NETCDF_LOCK, netCDF4.Dataset(path) as nc:
        has_polygon = "survey_polygon_wkt" in nc.ncattrs()
    try:
        result = compute_coverage([Path(path)], cell_m=float(cell_m),
                                  region="survey" if has_polygon else "scene",
                                  min_detections=1)
    except ValueError as exc:   # coverage.CoverageError: one line naming the option
        raise ConfigError(str(exc)) from None
    return float(result.summary["fraction_covered"])
