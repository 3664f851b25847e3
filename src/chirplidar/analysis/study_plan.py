"""The plan of a mission study (:mod:`chirplidar.analysis.study`): every point of the grid
prepared and checked before the first one runs.

Every point is the mission with ``--set``, then the point's values, then (``span_s``)
``survey.stop_s = survey.start_s + span_s`` of that point. Before the first point runs, every
point is prepared (:func:`chirplidar.mission.preflight.prepare`: configuration, scene file with the
point's scene keys, survey plan) and its span checked, so a bad value of any point (an unknown
material, an altitude under the terrain, a span past the mission's end) stops the study before
any work. Every point runs with the same seed (``seed``, else the mission's): the points differ
only by the varied keys, not by their random draws' seeds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config.loader import ConfigError, config_with, load_mission, parse_set, resolve_key
from .study_grid import VaryAxis, parse_vary, toml_literal

MAX_KEYS = 2


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
    from ..mission.preflight import TIERS

    mission_path = Path(mission_path)
    axes, seen = _checked_axes(vary)
    overrides = tuple(str(o) for o in overrides)
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

    points = tuple(_plan_point(mission_path, axes, index, overrides, span_s=span_s,
                               cell_m=cell_m, tier=tier, seed=seed, cache_dir=cache_dir)
                   for index in np.ndindex(*[len(a.values) for a in axes]))
    tier_name = tier if tier is not None else (
        base.survey.tier if base.survey is not None else "")
    if "survey.tier" in seen:
        tier_name = "varied"
    return StudyPlan(mission_path=mission_path, axes=axes, points=points,
                     overrides=overrides, seed=seed, tier=tier_name, span_s=span_s,
                     cell_m=cell_m)


def _checked_axes(vary: Sequence) -> tuple[tuple[VaryAxis, ...], dict]:
    """(the axes of ``vary``, {mission key: key as given}); ConfigError for none, more than
    MAX_KEYS or a key given twice."""
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
    return axes, seen


def _plan_point(mission_path: Path, axes, index, overrides: tuple, *, span_s, cell_m, tier,
                seed: int, cache_dir) -> StudyPoint:
    """The point ``index`` of the grid, prepared (configuration, scene, plan) and checked: its
    span within the mission, a shot in it, ``cell_m`` within its region."""
    from ..mission.preflight import prepare
    from ..mission.survey import check_crosses_scene, plan_survey

    values = {a.key: a.values[i] for a, i in zip(axes, index)}
    point_over = list(overrides) + [f"{a.mission_key}={toml_literal(a.values[i])}"
                                    for a, i in zip(axes, index)]
    label = ", ".join(f"{k}={toml_literal(v)}" for k, v in values.items())
    try:
        config, scene, plan = prepare(mission_path, overrides=point_over, tier=tier,
                                      seed=seed, cache_dir=cache_dir)
    except ConfigError as exc:
        raise ConfigError(f"at {label}: {strip_source(exc)}") from None
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
                              f"{strip_source(exc)}") from None
    n_shots = plan.n_shots
    if n_shots == 0:
        raise ConfigError(f"at {label}: the survey span holds no shot "
                          f"(survey.prf_hz = {sv.prf_hz:g} Hz)")
    if cell_m is not None:
        _check_cell(cell_m, config, scene, label)
    # A pulsed instrument detects with its own threshold (pulse_ranging.threshold_sigma).
    threshold = float("nan") if config.kind == "pulsed" else float(sv.detection_threshold_db)
    return StudyPoint(tuple(int(i) for i in index), values, tuple(point_over), threshold,
                      n_shots, int(plan.beams.n_beams))


def _check_cell(cell_m: float, config, scene, label: str) -> None:
    """``cell_m`` must fit in the coverage region of the point: its survey polygon, else the
    scene's extent (as :func:`~chirplidar.analysis.study_metrics.coverage_fraction` chooses)."""
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


def strip_source(exc: Exception) -> str:
    """A ConfigError's message without the ``--set: `` or ``override: `` it starts with (the
    study names the point or option instead)."""
    return str(exc).removeprefix("--set: ").removeprefix("override: ")
