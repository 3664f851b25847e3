"""Mission studies (``chirplidar study``): a survey mission on a grid of one or two mission keys.

What a study answers: how detection, SNR, received power, ranging and (optionally) coverage of a
survey change with the flight altitude, the line spacing, the laser power, the telescope, the
surface material, the threshold, ... before anybody flies it.

Example::

    # the whole demo survey at 4 altitudes x 2 line spacings, with the covered fraction of
    # 50 m cells (8 runs of up to 310 000 shots, ~2 minutes on 2 cores)
    chirplidar study missions/greenland_uav.toml --vary platform.uav.altitude_m=60:480:4:log \\
        --vary platform.uav.line_spacing_m=100,200 --cell-m 50 --plot outputs/altitude.png \\
        --out outputs/altitude_study.nc
    # laser power over the first 20 s of the survey, link tier, as JSON
    chirplidar study missions/greenland_uav.toml --vary lsr.Po=0.002:0.02:5:log --span-s 20 \\
        --tier link --json
    # a flat-scene mission: the surface material (scene key) against the altitude
    chirplidar study my_flat_mission.toml --vary scene.terrain.flat.material=snow,firn,blue_ice \\
        --vary platform.uav.altitude_m=100:1000:10 --span-s 5 --plot outputs/materials.png

    from chirplidar.analysis.study import run_study
    ds = run_study("missions/greenland_uav.toml", ["lsr.Po=0.005:0.05:5:log"], span_s=20.0,
                   tier="link")
    print(ds.median_snr_db.values, ds.detection_probability.values)

Grid
----
``--vary KEY=START:STOP:N`` is N >= 2 values from START to STOP, evenly spaced (add ``:log`` for
geometric spacing, ``:lin`` is the default); integers when START and STOP are written as integers
and every value is one. ``--vary KEY=V1,V2,...`` lists the values, each read as ``--set`` reads a
value (a TOML literal, else a bare string: ``snow,blue_ice``); commas inside ``[...]`` or quotes do
not split (``beams.off_nadir_deg=[0.0],[15.0]``). KEY is any key ``--set`` accepts (thesis names
too, and ``scene.<scene key>``). At most two keys, each once; a key may not also be in ``--set``.

Every point is the mission with ``--set``, then the point's values, then (``span_s``)
``survey.stop_s = survey.start_s + span_s`` of that point. Before the first point runs, every
point is prepared (:func:`chirplidar.mission.preflight.prepare`: configuration, scene file with the
point's scene keys, survey plan) and its span checked, so a bad value of any point (an unknown
material, an altitude under the terrain, a span past the mission's end) stops the study before
any work. Every point runs with the same seed (``seed``, else the mission's): the points differ
only by the varied keys, not by their random draws' seeds.

Each point is one :func:`~chirplidar.mission.runner.run_mission` into a temporary directory (beside
``out`` when given, else the system's; removed after the point's metrics are read), with
``workers``/``scheduler`` passed through (the same Dask options as ``chirplidar run``; with
``scheduler`` the workers must see the temporary directory: give ``out`` on shared storage).

Metrics of a point (:func:`point_metrics`), read from its results file chunk by chunk
---------------------------------------------------------------------------------------
"surface shots": shot-beams with a surface in the beam (``detected != 2``), detected or not.

==============================  =====  ===================================================
``detection_probability``       1      detected / surface shots
``median_snr_db``               dB     median of ``snr_db`` over the surface shots
``snr_p10_db``, ``snr_p90_db``  dB     10th and 90th percentiles of the same (the fades)
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
==============================  =====  ===================================================

A surface shot with no signal (zero received power; its ``snr_db`` is NaN in the results file,
"no value" since 10 log10(0) is not stored) counts as -inf dB in the SNR and power statistics, so
it pulls a median or percentile down instead of being dropped; a quantile that falls on (or
interpolates with) such a shot is -inf. No NaN, no warning. Quantiles are numpy's
(``np.percentile``, ``method="linear"``, for the 10th and 90th percentiles; ``np.median``, the
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

The study dataset
-----------------
One dimension per varied key, named after the resolved mission key with every character outside
[A-Za-z0-9_] replaced by ``_`` (``platform.uav.altitude_m`` -> ``platform_uav_altitude_m``,
``lsr.Po`` -> ``laser_power_w``); the coordinate holds the values (strings for string values)
with ``long_name``, ``units`` (from the key's suffix: ``_m`` m, ``_deg`` degree, ``_w`` W,
``_mps`` m s-1, ``_db`` dB, ... ``1`` for dimensionless keys and labels), ``study_key`` (as given)
and ``mission_key`` (resolved). Every metric has ``units`` and ``long_name``. Global attributes:
mission file, seed, tier, span, ``--set`` list, ``--vary`` specs, cell size, software version.
"""

from __future__ import annotations

import json
import math
import re
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from .. import _checks
from ..config.loader import (
    ConfigError,
    _known,
    _unknown_key_message,
    config_with,
    load_mission,
    resolve_key,
)
from ..mission.summary import quantile_between, quantile_ranks

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

MAX_KEYS = 2

#: The metrics of a point, in table order: name -> (units, long_name).
METRICS: dict[str, tuple[str, str]] = {
    "detection_probability": ("1", "detected shot-beams / shot-beams with a surface in the beam"),
    "median_snr_db": ("dB", ("median SNR in the RBW over the shot-beams with a surface in "
                             "the beam (zero signal counts as -inf dB)")),
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
_COUNTS = ("shots", "detected_shots")

_DETECTED, _NO_SURFACE = 1, 2
#: Stands for -inf (zero signal) in the radix select, which takes finite values: below every
#: finite dB value a results file can hold.
_NEG_SENTINEL = -np.finfo(np.float64).max
_DEFAULT_OBS_BLOCK = 20000

# Key suffix -> (CF units, axis-label units); longest suffix first.
_SUFFIX_UNITS: tuple[tuple[str, str, str], ...] = (
    ("_m_minus_2_3", "m-2/3", "m$^{-2/3}$"),
    ("_a_per_rthz", "A Hz-1/2", "A/$\\sqrt{Hz}$"),
    ("_v_per_rthz", "V Hz-1/2", "V/$\\sqrt{Hz}$"),
    ("_w_per_rthz", "W Hz-1/2", "W/$\\sqrt{Hz}$"),
    ("_hz_per_s", "Hz s-1", "Hz/s"),
    ("_per_m", "m-1", "1/m"),
    ("_rad_rms", "rad", "rad rms"),
    ("_deg_s", "degree s-1", "deg/s"),
    ("_mps", "m s-1", "m/s"),
    ("_dbm", "dBm", "dBm"),
    ("_db", "dB", "dB"),
    ("_deg", "degree", "deg"),
    ("_rad", "rad", "rad"),
    ("_hz", "Hz", "Hz"),
    ("_ohm", "ohm", "ohm"),
    ("_m2", "m2", "m$^2$"),
    ("_m", "m", "m"),
    ("_s", "s", "s"),
    ("_w", "W", "W"),
    ("_v", "V", "V"),
    ("_a", "A", "A"),
    ("_k", "K", "K"),
    ("_f", "F", "F"),
)


def key_units(key: str) -> tuple[str, str]:
    """(CF units, axis-label units) of a mission key from its SI suffix (``_m``, ``_deg``,
    ``_w``, ``_mps``, ``_db``, ...); ``("1", "")`` for a key without one."""
    leaf = resolve_key(key).rsplit(".", 1)[-1].lower()
    for suffix, cf, label in _SUFFIX_UNITS:
        if leaf.endswith(suffix):
            return cf, label
    return "1", ""


def dim_name(mission_key: str) -> str:
    """NetCDF-safe dimension name of a resolved mission key (``platform.uav.altitude_m`` ->
    ``platform_uav_altitude_m``)."""
    name = re.sub(r"[^0-9A-Za-z_]", "_", mission_key)
    return name if name[:1].isalpha() else f"v_{name}"


# ------------------------------------------------------------------------------------- the grid
def toml_literal(value) -> str:
    """``value`` as the TOML literal that :func:`chirplidar.config.parse_set` reads back equal:
    the override text of a point (``key=<literal>``)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        f = float(value)
        if math.isnan(f):
            return "nan"
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        return repr(f)
    if isinstance(value, str):
        return json.dumps(value)   # a JSON string is a valid TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    raise ConfigError(f"cannot use the value {value!r} ({type(value).__name__}) in a study")


def _split_top(text: str, sep: str) -> list[str]:
    """``text`` split at ``sep`` outside brackets and quotes."""
    parts, depth, quote, cur = [], 0, None, []
    for ch in text:
        if quote:
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == sep and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


def _literal(raw: str):
    """A value as ``--set`` reads it: a TOML literal, else the bare text as a string. TOML
    dates and times stay text (the configuration holds them as strings)."""
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw
    if not _plain(value):
        return raw
    return value


def _plain(value) -> bool:
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return isinstance(value, (bool, int, float, str))


def _number(raw: str, spec: str, what: str):
    value = _literal(raw)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ConfigError(f"--vary {spec}: {what} {raw.strip()!r} is not a finite number "
                          "(expected KEY=START:STOP:N[:log] or KEY=V1,V2,...)")
    return value


@dataclass(frozen=True)
class VaryAxis:
    """One varied key: ``key`` as given, ``mission_key`` resolved (thesis names translated),
    its ``values`` (Python scalars or lists, as ``--set`` would read them), ``spacing``
    (``lin``, ``log`` or ``list``) and the ``spec`` text."""

    spec: str
    key: str
    mission_key: str
    values: tuple
    spacing: str

    @property
    def dim(self) -> str:
        return dim_name(self.mission_key)


def parse_vary(spec: str) -> VaryAxis:
    """Parse ``KEY=START:STOP:N[:log|:lin]`` or ``KEY=V1,V2,...`` (module docstring); ConfigError
    naming the spec for an unknown key, a malformed range, N < 2, or a repeated value."""
    if not isinstance(spec, str) or "=" not in spec:
        raise ConfigError(f"--vary {spec!r}: expected KEY=START:STOP:N[:log] or KEY=V1,V2,...")
    key, raw = (s.strip() for s in spec.split("=", 1))
    if not key:
        raise ConfigError(f"--vary {spec}: no key before '='")
    mission_key = resolve_key(key)
    if not _known(mission_key):
        raise ConfigError(_unknown_key_message(key, "--vary"))
    if not raw:
        raise ConfigError(f"--vary {spec}: no values after '=' (expected START:STOP:N[:log] "
                          "or V1,V2,...)")
    items = _split_top(raw, ",")
    fields = _split_top(raw, ":")
    quoted = raw[:1] in "\"'"
    if len(items) == 1 and len(fields) > 1 and not quoted:
        if len(fields) not in (3, 4):
            raise ConfigError(f"--vary {spec}: a range is START:STOP:N or START:STOP:N:log "
                              f"(got {len(fields)} fields)")
        spacing = fields[3].strip().lower() if len(fields) == 4 else "lin"
        if spacing not in ("lin", "log"):
            raise ConfigError(f"--vary {spec}: range spacing must be 'lin' or 'log', got "
                              f"{fields[3].strip()!r}")
        start = _number(fields[0], spec, "START")
        stop = _number(fields[1], spec, "STOP")
        n = _literal(fields[2])
        if isinstance(n, bool) or not isinstance(n, int):
            raise ConfigError(f"--vary {spec}: N {fields[2].strip()!r} must be an integer "
                              "number of values >= 2")
        if n < 2:
            raise ConfigError(f"--vary {spec}: a range needs N >= 2 values (got N = {n}); for "
                              "one value use --set")
        if start == stop:
            raise ConfigError(f"--vary {spec}: START and STOP are equal")
        if spacing == "log":
            if start <= 0 or stop <= 0:
                raise ConfigError(f"--vary {spec}: a log range needs START and STOP > 0")
            xs = np.geomspace(float(start), float(stop), n)
        else:
            xs = np.linspace(float(start), float(stop), n)
        whole = isinstance(start, int) and isinstance(stop, int) and np.all(xs == np.round(xs))
        values = tuple(int(np.rint(x)) for x in xs) if whole else tuple(float(x) for x in xs)
        if len(set(values)) != len(values):
            raise ConfigError(f"--vary {spec}: the range repeats values {list(values)}")
        return VaryAxis(spec, key, mission_key, values, spacing)
    if any(not it.strip() for it in items):
        raise ConfigError(f"--vary {spec}: an empty value in the list (expected V1,V2,...)")
    values = tuple(_literal(it) for it in items)
    if len(values) < 2:
        raise ConfigError(f"--vary {spec}: one value; give a list V1,V2,... or a range "
                          "START:STOP:N (use --set for a single value)")
    seen = set()
    for v in values:
        same = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) \
            else toml_literal(v)
        if same in seen:
            raise ConfigError(f"--vary {spec}: the value {toml_literal(v)} is listed twice")
        seen.add(same)
    return VaryAxis(spec, key, mission_key, values, "list")


def _coordinate(axis: VaryAxis) -> tuple[np.ndarray, str]:
    """(coordinate values, 'number' | 'string') of an axis: numbers as float64 (int64 when all
    are integers), one-element numeric lists as their number, anything else as its TOML text."""
    vals = axis.values
    num = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)
    if all(num(v) for v in vals):
        if all(isinstance(v, int) for v in vals):
            return np.array(vals, dtype=np.int64), "number"
        return np.array(vals, dtype=np.float64), "number"
    if all(isinstance(v, list) and len(v) == 1 and num(v[0]) for v in vals):
        return np.array([float(v[0]) for v in vals]), "number"
    return np.array([v if isinstance(v, str) else toml_literal(v) for v in vals], dtype=str), \
        "string"


@dataclass(frozen=True)
class StudyPoint:
    """One grid point: its index along each axis, values ({key as given: value}), the override
    list of its run (``--set`` then the point's keys then the span), its detection threshold
    and shot count (from its plan)."""

    index: tuple
    values: dict
    overrides: tuple
    detection_threshold_db: float
    n_shots: int
    n_beams: int

    def label(self) -> str:
        return ", ".join(f"{k}={toml_literal(v)}" for k, v in self.values.items())


@dataclass(frozen=True)
class StudyPlan:
    """A checked study: axes, points (C order over the axes), seed, tier and span."""

    mission_path: Path
    axes: tuple
    points: tuple
    overrides: tuple
    seed: int
    tier: str
    span_s: float | None
    cell_m: float | None

    @property
    def shape(self) -> tuple:
        return tuple(len(a.values) for a in self.axes)


def _check_positive(name: str, value) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)) or float(value) <= 0:
        raise ConfigError(f"{name} must be a finite number > 0 (got {value!r})")
    return float(value)


def plan_study(mission_path, vary: Sequence, *, overrides=(), span_s=None, cell_m=None,
               tier=None, seed=None, cache_dir=None) -> StudyPlan:
    """Parse and check a whole study before any point runs: ConfigError (one line naming the
    key, value or option) for a bad ``--vary`` spec, more than two keys, a key varied twice or
    also in ``overrides``, a varied ``seed`` (every point uses the same seed), ``survey.tier``
    varied with ``tier`` given, ``survey.stop_s`` varied with ``span_s``, a bad ``span_s`` or
    ``cell_m``, and any point whose mission, scene or plan does not load
    (:func:`chirplidar.mission.preflight.prepare` of every point)."""
    from ..mission.preflight import TIERS, prepare
    from ..mission.survey import check_crosses_scene, plan_survey

    mission_path = Path(mission_path)
    axes = tuple(a if isinstance(a, VaryAxis) else parse_vary(a) for a in vary)
    if not axes:
        raise ConfigError("--vary: a study needs at least one --vary KEY=...")
    if len(axes) > MAX_KEYS:
        raise ConfigError(f"--vary: at most {MAX_KEYS} keys per study, got {len(axes)} "
                          f"({', '.join(a.key for a in axes)})")
    seen = {}
    for a in axes:
        if a.mission_key in seen:
            both = seen[a.mission_key]
            same = a.key if a.key == both else f"{both} and {a.key} are both {a.mission_key}"
            raise ConfigError(f"--vary: the key {same} is given twice")
        seen[a.mission_key] = a.key
    overrides = tuple(str(o) for o in overrides)
    from ..config.loader import parse_set

    for o in overrides:
        k = resolve_key(parse_set(o)[0])
        if k in seen:
            raise ConfigError(f"--vary {seen[k]}: also given in --set ({o}); give it in one "
                              "place")
    if "seed" in seen:
        raise ConfigError("--vary seed: a study runs every point with the same seed; pass "
                          "--seed N, and run separate studies for other seeds")
    if tier is not None and tier not in TIERS:
        raise ConfigError(f"--tier {tier}: choose one of {', '.join(TIERS)}")
    if tier is not None and "survey.tier" in seen:
        raise ConfigError(f"--vary {seen['survey.tier']}: the tier is varied; leave out --tier")
    span_s = _check_positive("--span-s", span_s)
    if span_s is not None and "survey.stop_s" in seen:
        raise ConfigError(f"--vary {seen['survey.stop_s']}: --span-s sets survey.stop_s of "
                          "every point; vary one or give the other")
    cell_m = _check_positive("--cell-m", cell_m)
    if cell_m is not None:
        try:
            from . import coverage  # noqa: F401
        except ImportError as exc:
            raise ConfigError(f"--cell-m needs chirplidar.analysis.coverage, which cannot be "
                              f"imported ({exc})") from None
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                             or seed < 0):
        raise ConfigError(f"--seed must be an integer >= 0, got {seed!r}")
    if not mission_path.is_file():
        raise ConfigError(f"{mission_path}: mission file does not exist")
    base = load_mission(mission_path, list(overrides))
    seed = int(base.seed if seed is None else seed)

    points = []
    for index in np.ndindex(*[len(a.values) for a in axes]):
        values = {a.key: a.values[i] for a, i in zip(axes, index)}
        point_over = list(overrides) + [f"{a.mission_key}={toml_literal(a.values[i])}"
                                        for a, i in zip(axes, index)]
        label = ", ".join(f"{k}={toml_literal(v)}" for k, v in values.items())
        try:
            config, scene, plan = prepare(mission_path, overrides=point_over, tier=tier,
                                          seed=seed, cache_dir=cache_dir)
        except ConfigError as exc:
            raise ConfigError(f"at {label}: {_strip_source(exc)}") from None
        sv = config.survey
        if span_s is not None:
            # The mission's stop: survey.stop_s, else the end of the path (a satellite
            # mission must state survey.stop_s: prepare has checked).
            end = sv.stop_s if sv.stop_s is not None else float(plan.path.duration_s)
            avail = end - sv.start_s
            if span_s > avail * (1 + 1e-12):
                raise ConfigError(
                    f"--span-s {span_s:g}: beyond the mission's stop at {label}: survey.start_s "
                    f".. stop = {sv.start_s:g} .. {end:g} s ({avail:g} s)")
            stop = sv.start_s + span_s
            point_over.append(f"survey.stop_s={toml_literal(float(stop))}")
            try:
                cfg_span = config_with(config, {"survey.stop_s": float(stop)})
                plan = plan_survey(cfg_span, scene, str(mission_path))
                check_crosses_scene(plan, scene, cfg_span, str(mission_path))
            except ConfigError as exc:
                raise ConfigError(f"--span-s {span_s:g} at {label}: "
                                  f"{_strip_source(exc)}") from None
        n_shots = plan.n_shots
        if n_shots == 0:
            raise ConfigError(f"at {label}: the survey span holds no shot "
                              f"(survey.prf_hz = {sv.prf_hz:g} Hz)")
        if cell_m is not None:
            _check_cell(cell_m, config, scene, label)
        points.append(StudyPoint(tuple(int(i) for i in index), values, tuple(point_over),
                                 float(sv.detection_threshold_db), n_shots,
                                 int(plan.beams.n_beams)))
        del config, scene, plan
    tier_name = tier if tier is not None else (
        base.survey.tier if base.survey is not None else "")
    if "survey.tier" in seen:
        tier_name = "varied"
    return StudyPlan(mission_path=mission_path, axes=axes, points=tuple(points),
                     overrides=overrides, seed=seed, tier=tier_name, span_s=span_s,
                     cell_m=cell_m)


def _check_cell(cell_m: float, config, scene, label: str) -> None:
    """``cell_m`` must fit in the coverage region of the point: its survey polygon, else the
    scene's extent (as :func:`coverage_fraction` chooses)."""
    from ..mission.survey import survey_polygon_xy

    polygon = survey_polygon_xy(config, scene)
    if polygon is not None:
        xy = np.asarray(polygon, float)
        size = max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1]))
        what = "survey polygon"
    else:
        x0, x1, y0, y1 = scene.bounds_xy
        size = max(x1 - x0, y1 - y0)
        what = "scene"
    if cell_m > size:
        raise ConfigError(f"--cell-m {cell_m:g}: larger than the {what} ({size:.0f} m across) "
                          f"at {label}")


def _strip_source(exc: Exception) -> str:
    return str(exc).removeprefix("--set: ").removeprefix("override: ")


# ---------------------------------------------------------------------------- point metrics
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


_QUANTILES = {"snr_p10_db": 0.10, "median_snr_db": 0.50, "snr_p90_db": 0.90}


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
    """The metrics of one run's results file (module docstring), read ``obs_block``
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
            back = lambda v: -math.inf if v == _NEG_SENTINEL else v
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


# ---------------------------------------------------------------------------------- running
def run_study(mission_path, vary: Sequence, *, overrides=(), span_s: float | None = None,
              cell_m: float | None = None, tier: str | None = None, seed: int | None = None,
              workers: int | None = None, scheduler: str | None = None,
              progress: bool = False, out=None, overwrite: bool = False, cache_dir=None,
              on_point: Callable | None = None,
              budget_bytes: int | None = None,
              before_write: Callable | None = None) -> xr.Dataset:
    """Run the survey mission at every point of the grid of ``vary`` (one or two specs
    ``KEY=START:STOP:N[:log]`` / ``KEY=V1,V2,...`` or :class:`VaryAxis`) and return the study
    dataset (module docstring); with ``out`` (``.nc``) also write it atomically.

    ``overrides``: the ``--set`` list, applied to every point before its values; ``span_s``:
    run ``survey.start_s .. start_s + span_s`` of each point (else the whole mission); ``tier``
    (``link``, ``baseband``, ``rf``) and ``seed``: as ``chirplidar run`` (the same seed at every
    point); ``workers``/``scheduler``: passed to every point's run; ``progress``: a bar over the
    points. ``on_point(point, path, metrics)`` (a test hook) is called after each point's
    metrics, while its results file still exists. ``before_write(ds)`` is called once every
    point has run, before ``out`` is written (``chirplidar study`` draws its plot there, so that a
    plot that cannot be written leaves no study file behind): when it returns False ``out`` is
    not written, and an exception from it propagates with nothing written. An existing ``out``
    raises FileExistsError before any work unless ``overwrite``; an ``out`` that is a directory,
    or in a directory that is missing or cannot be written, raises ConfigError before any work
    (:func:`check_output_file`). Everything is checked (:func:`plan_study`) before the first
    point runs.
    """
    from ..mission.executors import check_parallel_args
    from ..mission.runner import run_mission

    try:
        check_parallel_args(workers, scheduler)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if out is not None:
        out = Path(out)
        if out.suffix != ".nc":
            raise ConfigError(f"--out {out}: the study file must end in .nc")
        if out.is_dir():
            raise ConfigError(f"--out {out}: is a directory; name the study file "
                              "(e.g. study.nc)")
        if out.exists() and not overwrite:
            raise FileExistsError(f"{out} exists: pass --overwrite to replace it "
                                  "(nothing was run)")
        if not out.parent.is_dir():
            raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
        check_output_file("--out", out, ".nc")
    plan = plan_study(mission_path, vary, overrides=overrides, span_s=span_s, cell_m=cell_m,
                      tier=tier, seed=seed, cache_dir=cache_dir)
    t0 = time.perf_counter()
    metrics = {name: np.full(plan.shape, np.nan) for name in METRICS}
    metrics["shots"] = np.zeros(plan.shape, dtype=np.int64)
    metrics["detected_shots"] = np.zeros(plan.shape, dtype=np.int64)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(plan.points), unit="point", desc="study", leave=False)
    temp_parent = None if out is None else str(out.parent)
    try:
        for point in plan.points:
            if bar is not None:
                bar.set_postfix_str(point.label(), refresh=False)
            with tempfile.TemporaryDirectory(prefix=".chirplidar-study-",
                                             dir=temp_parent) as tmp:
                path = Path(tmp) / "point.nc"
                try:
                    run_mission(plan.mission_path, overrides=list(point.overrides), tier=tier,
                                out=path, seed=plan.seed, progress=False, cache_dir=cache_dir,
                                workers=workers, scheduler=scheduler)
                except ConfigError as exc:
                    raise ConfigError(f"at {point.label()}: {_strip_source(exc)}") from None
                values = point_metrics(path, detection_threshold_db=point.detection_threshold_db,
                                       cell_m=plan.cell_m, budget_bytes=budget_bytes)
                if on_point is not None:
                    on_point(point, path, values)
            for name, value in values.items():
                metrics[name][point.index] = value
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    ds = study_dataset(plan, metrics, elapsed_s=time.perf_counter() - t0)
    write = True
    if before_write is not None:
        write = before_write(ds) is not False
    if out is not None and write:
        write_study(ds, out, overwrite=overwrite)
    return ds


def check_output_file(option: str, path, suffix: str, *, make_parents: bool = False) -> Path:
    """:func:`chirplidar._checks.writable_file`, its error a ConfigError (one line, exit 2)."""
    try:
        return _checks.writable_file(option, path, suffix, make_parents=make_parents)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def study_dataset(plan: StudyPlan, metrics: dict, *, elapsed_s: float | None = None,
                  date_created: str | None = None) -> xr.Dataset:
    """The study dataset of ``plan`` from metric arrays shaped like the grid."""
    from .. import __version__
    from ..mission.manifest import default_date_created

    dims = tuple(a.dim for a in plan.axes)
    coords = {}
    for a in plan.axes:
        values, kind = _coordinate(a)
        units, _ = key_units(a.mission_key) if kind == "number" else ("1", "")
        named = a.key if a.key == a.mission_key else f"{a.key} ({a.mission_key})"
        attrs = {"long_name": f"varied mission key {named}", "units": units,
                 "study_key": a.key, "mission_key": a.mission_key, "spacing": a.spacing,
                 "vary_spec": a.spec}
        if kind == "number" and any(isinstance(v, list) for v in a.values):
            attrs["comment"] = "each value is the one element of the list given to the key"
        coords[a.dim] = ((a.dim,), values, attrs)
    data_vars = {}
    for name, (units, long_name) in METRICS.items():
        if name == "fraction_covered" and plan.cell_m is None:
            continue
        attrs = {"units": units, "long_name": long_name}
        if name == "fraction_covered":
            attrs["cell_size_m"] = float(plan.cell_m)
        data_vars[name] = (dims, np.asarray(metrics[name]), attrs)
    date_created = date_created or default_date_created()
    source = f"chirplidar {__version__}"
    span = ("the whole mission" if plan.span_s is None
            else f"survey.start_s .. survey.start_s + {plan.span_s:g} s")
    attrs = {
        "Conventions": "CF-1.8",
        "title": f"chirplidar mission study: {plan.mission_path.stem} over "
                 f"{' x '.join(a.key for a in plan.axes)}",
        "source": source,
        "history": f"{date_created} {source}: chirplidar study of {plan.mission_path}",
        "date_created": date_created,
        "software_version": __version__,
        "mission_file": str(plan.mission_path),
        "seed": np.int64(plan.seed),
        "tier": plan.tier,
        "span": span,
        "set_overrides": json.dumps(list(plan.overrides)),
        "vary": json.dumps([a.spec for a in plan.axes]),
        "points": np.int64(len(plan.points)),
    }
    if plan.span_s is not None:
        attrs["span_s"] = float(plan.span_s)
    if plan.cell_m is not None:
        attrs["cell_m"] = float(plan.cell_m)
    if elapsed_s is not None:
        attrs["elapsed_s"] = float(elapsed_s)
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def write_study(ds: xr.Dataset, path, *, overwrite: bool = False) -> Path:
    """Write a study dataset to NetCDF atomically (temp file beside it, fsync, rename); an
    existing ``path`` raises FileExistsError unless ``overwrite``. NaN is the fill value of
    the float metrics (no value); -inf stays -inf (zero signal)."""
    from ..mission.results import NETCDF_LOCK, write_atomic

    for name, var in ds.variables.items():
        if "units" not in var.attrs or "long_name" not in var.attrs:
            raise ValueError(f"study variable {name!r} needs units and long_name")
    encoding = {name: {"_FillValue": np.nan} for name, var in ds.data_vars.items()
                if np.issubdtype(var.dtype, np.floating)}
    encoding.update({name: {"_FillValue": None} for name, var in ds.variables.items()
                     if np.issubdtype(var.dtype, np.integer)})

    def write(tmp):
        with NETCDF_LOCK:
            ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=encoding)

    return write_atomic(Path(path), write, overwrite=overwrite)


# ---------------------------------------------------------------------------------- reporting
def _axis_dims(ds: xr.Dataset) -> list[str]:
    return [d for d in ds["detection_probability"].dims]


def study_records(ds: xr.Dataset) -> list[dict]:
    """One dict per point (C order over the varied keys): each varied key as given (its
    value), then the metrics (Python floats, -inf/NaN as they are; JSON writers map them)."""
    dims = _axis_dims(ds)
    names = [n for n in METRICS if n in ds.data_vars]
    records = []
    for index in np.ndindex(*[ds.sizes[d] for d in dims]):
        rec = {}
        for d, i in zip(dims, index):
            v = ds[d].values[i]
            rec[str(ds[d].attrs.get("study_key", d))] = v.item() if hasattr(v, "item") else v
        for n in names:
            v = ds[n].values[index]
            rec[n] = int(v) if n in _COUNTS else float(v)
        records.append(rec)
    return records


def _fmt(value, scale: float = 1.0, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "-inf" if value < 0 else "inf"
    return f"{value * scale:.{digits}f}"


def format_study(ds: xr.Dataset) -> str:
    """A readable table of a study: one row per point."""
    dims = _axis_dims(ds)
    keys = [str(ds[d].attrs.get("study_key", d)) for d in dims]
    cols = [("P_det", "%", "detection_probability", 100.0, 1),
            ("SNR p50", "dB", "median_snr_db", 1.0, 1),
            ("p10", "dB", "snr_p10_db", 1.0, 1),
            ("p90", "dB", "snr_p90_db", 1.0, 1),
            ("Psig p50", "dBm", "median_received_power_dbm", 1.0, 1),
            ("range RMS", "cm", "range_rms_m", 100.0, 2),
            ("h prec", "cm", "height_precision_m", 100.0, 2)]
    if "fraction_covered" in ds.data_vars:
        cols.append(("covered", "%", "fraction_covered", 100.0, 1))
    cols += [("flight", "s", "flight_time_s", 1.0, 1),
             ("shots", "", "shots", 1.0, 0)]
    if "detected_shots" in ds.data_vars:   # study files written before it existed lack it
        cols.append(("detected", "", "detected_shots", 1.0, 0))
    cols.append(("threshold", "dB", "detection_threshold_db", 1.0, 1))
    key_w = [max(len(k), 10) for k in keys]
    col_w = [max(len(c[0]), len(c[1]) + 2, 8) for c in cols]
    head1 = "  ".join(k.rjust(w) for k, w in zip(keys, key_w)) + "  " + "  ".join(
        c[0].rjust(w) for c, w in zip(cols, col_w))
    units = []
    for d, w in zip(dims, key_w):
        u = ds[d].attrs.get("units", "1")
        units.append((f"({u})" if u not in ("1", "") else "").rjust(w))
    head2 = "  ".join(units) + "  " + "  ".join(
        (f"({c[1]})" if c[1] else "").rjust(w) for c, w in zip(cols, col_w))
    span = ds.attrs.get("span", "")
    header = (f"chirplidar study: {ds.attrs.get('mission_file', '')}, "
              f"{int(ds.attrs.get('points', 0))} points, tier {ds.attrs.get('tier', '')}, "
              f"seed {int(ds.attrs.get('seed', 0))}, span {span}")
    lines = [header, head1, head2]
    for rec in study_records(ds):
        row = []
        for k, w in zip(keys, key_w):
            v = rec[k]
            row.append((f"{v:.6g}" if isinstance(v, float) else str(v)).rjust(w))
        for (label, _, name, scale, digits), w in zip(cols, col_w):
            v = rec[name]
            row.append((str(v) if name in _COUNTS else _fmt(v, scale, digits)).rjust(w))
        lines.append("  ".join(row))
    return "\n".join(lines)
