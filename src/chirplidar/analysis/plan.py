"""Flight plans (``chirplidar plan``): the line spacing, and the altitude, speed or heading when
asked, that meet a coverage and precision requirement at the least flight time, checked against
what the platform can fly.

Example::

    chirplidar plan missions/greenland_uav.toml --cell-m 100 --min-covered 0.95 --out plans/demo
    chirplidar run plans/demo/mission.toml && chirplidar coverage outputs/mission.nc --cell-m 100

Requirement (over the mission's survey polygon, :mod:`chirplidar.analysis.coverage`): at least
``min_covered`` of the cells of ``cell_m`` hold ``min_detections`` detected shots, and (when
given) the median over the covered cells of the precision of the cell's mean height (the grid's
``height_precision_measured``: one shot's height error over sqrt(N)) is at most
``max_height_precision_m``. A plan must also fit the platform: the whole path within
``platform.<kind>.endurance_s``; a UAV following the terrain flies the climb-limited profile of
``max_climb_mps`` / ``max_descent_mps`` (its clearance range is reported) and cannot fly lines
closer than twice its ``turn_radius_m`` (when given); an aircraft turns on ``turn_radius_m`` (the
turns are in its flight time and its waypoints).

Search. Every candidate is a full run of the mission (a temporary file) and its coverage: the
plan stands on the simulation, not on a geometric rule. Its covered fraction is the lower of two
grids, the region's and one shifted by half a cell in x and y: lines that fall on cell edges
cover both neighbouring rows in one grid, one row in the other, and a plan must not depend on
where the grid's lines fall. What is searched is the number of lines n across the polygon
(spacing = its width across the lines / n): flight time grows with n, and so do coverage and
a cell's precision (the property the bisection relies on), so the fewest lines that meet the
requirement are the quickest plan. It starts from lines one cell apart (a nadir line covers a
strip about one cell wide), halves or doubles n until the requirement flips (not beyond lines
an eighth of a cell apart: denser ones add nothing to a cell's coverage), then bisects to the
fewest lines. Among the ``--vary`` combinations the feasible candidate of least flight time wins
(ties: the better covered); if none is feasible, the report gives the best coverage any candidate
achieved and why it fell short.

Outputs (``write_plan``): ``mission.toml`` (``extends`` the mission, with the chosen keys, so
``run`` then ``coverage`` verify the plan), ``plan.geojson`` (lines and waypoints in WGS-84, with
ellipsoidal heights; opens in QGIS), ``mission.plan`` (QGroundControl: takeoff, waypoints, return
to launch) and ``plan.json`` (requirement, choice, candidates). The waypoints follow the simulated
flight: the path sampled every 0.5 s, thinned by Douglas-Peucker to 2 m across track and,
separately, in height (line ends, turn arcs, the terrain profile's changes of slope); the union
of the two can stray a little further (a few metres).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import tempfile
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..config.aliases import resolve_key
from ..config.loader import ConfigError, parse_set
from .study_grid import parse_vary, toml_literal

__all__ = ["Candidate", "PlanResult", "Requirement", "find_plan", "format_plan", "write_plan"]

WAYPOINT_TOLERANCE_M = 2.0    # the waypoints' path within this of the simulated one [m]
WAYPOINT_STEP_S = 0.5         # the simulated path sampled this often for the waypoints
MAX_EVALUATIONS = 14          # per combination: the bracket's widening and bisection


@dataclass(frozen=True)
class Requirement:
    cell_m: float
    min_covered: float
    min_detections: int = 1
    max_height_precision_m: float | None = None

    def __post_init__(self):
        if not (math.isfinite(self.cell_m) and self.cell_m > 0):
            raise ConfigError(f"--cell-m must be a positive number of metres, got {self.cell_m}")
        if not 0 < self.min_covered <= 1:
            raise ConfigError(f"--min-covered must lie in (0, 1], got {self.min_covered}")
        if self.min_detections < 1:
            raise ConfigError(f"--min-detections must be >= 1, got {self.min_detections}")
        p = self.max_height_precision_m
        if p is not None and not (math.isfinite(p) and p > 0):
            raise ConfigError(f"--max-height-precision-m must be > 0, got {p}")


@dataclass
class Candidate:
    """One run of the search: its keys, flight time and what it achieved."""

    overrides: dict                     # mission key -> value (the varied keys and spacing)
    line_spacing_m: float
    flight_time_s: float
    fraction_covered: float = float("nan")
    median_cell_precision_m: float = float("nan")   # of a covered cell's mean height
    shots: int = 0
    shortfalls: list = field(default_factory=list)   # why it does not meet the requirement
    profile: dict | None = None         # the UAV's clearance and vertical-rate range

    @property
    def feasible(self) -> bool:
        return not self.shortfalls


@dataclass
class PlanResult:
    mission: Path
    requirement: Requirement
    base_overrides: list
    candidates: list
    best: Candidate | None              # the quickest feasible candidate
    closest: Candidate                  # the best coverage achieved (when none is feasible)
    kind: str                           # "uav" or "aircraft"
    endurance_s: float | None

    @property
    def chosen(self) -> Candidate:
        return self.best if self.best is not None else self.closest


def _lawnmower_section(config):
    """(kind, [platform.uav] or [platform.aircraft]) of a lawnmower survey; ConfigError for a
    satellite or a waypoint path."""
    from ..mission.survey import flight_section

    sec = flight_section(config) if config.platform is not None else None
    if sec is None:
        raise ConfigError("plan is for UAV and aircraft missions (platform.kind = 'uav' or "
                          "'aircraft'); for satellites see `chirplidar passes`")
    kind = config.platform.kind
    if sec.survey_polygon_m is None:
        raise ConfigError(f"plan chooses the lawnmower over platform.{kind}.survey_polygon_m;"
                          " this mission flies waypoints")
    return kind, sec


def _evaluate(mission, base, over: dict, req: Requirement, endurance, workdir, workers,
              progress) -> Candidate:
    from ..mission.preflight import prepare
    from ..mission.runner import run_mission
    from .coverage import CoverageError, compute_coverage

    sets = list(base) + [f"{k}={toml_literal(v)}" for k, v in over.items()]
    with warnings.catch_warnings():   # endurance: judged below, as a shortfall
        warnings.simplefilter("ignore", UserWarning)
        config, _, plan = prepare(mission, overrides=sets)
    kind = config.platform.kind
    spacing = next(v for k, v in over.items() if k.endswith(".line_spacing_m"))
    cand = Candidate(dict(over), float(spacing), float(plan.path.duration_s))
    if hasattr(plan.path, "profile_report"):
        cand.profile = plan.path.profile_report()
    radius = _lawnmower_section(config)[1].turn_radius_m if kind == "uav" else None
    if radius is not None and spacing < 2 * radius:
        cand.shortfalls.append(f"lines {spacing:g} m apart, closer than twice the UAV's turn "
                               f"radius {radius:g} m: no U-turn from one to the next")
    if endurance is not None and cand.flight_time_s > endurance:
        cand.shortfalls.append(f"flight time {cand.flight_time_s:.0f} s exceeds the endurance "
                               f"{endurance:g} s")
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        out = Path(tmp) / "candidate.nc"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            run_mission(mission, overrides=sets, out=out, workers=workers)
        try:
            grid = compute_coverage([out], cell_m=req.cell_m, min_detections=req.min_detections)
            half = 0.5 * req.cell_m   # a plan must not hang on where the grid's lines fall
            shifted = compute_coverage([out], cell_m=req.cell_m,
                                       min_detections=req.min_detections,
                                       grid_shift_m=(half, half)).summary
        except CoverageError as exc:   # e.g. no shot detected at all: nothing covered
            cand.fraction_covered = 0.0
            cand.shortfalls.append(str(exc))
            return _report(cand, progress)
    s = grid.summary
    prec = grid.grid["height_precision_measured"].values[grid.grid["covered"].values == 1]
    prec = prec[np.isfinite(prec)]
    cand.fraction_covered = min(float(s["fraction_covered"]), float(shifted["fraction_covered"]))
    cand.median_cell_precision_m = float(np.median(prec)) if prec.size else float("nan")
    cand.shots = int(s["shots"])
    if not cand.fraction_covered >= req.min_covered:
        cand.shortfalls.append(f"covers {cand.fraction_covered:.3f} of the {req.cell_m:g} m "
                               f"cells, below {req.min_covered:g}")
    p = req.max_height_precision_m
    if p is not None and not cand.median_cell_precision_m <= p:
        cand.shortfalls.append(f"median precision of a cell's mean height "
                               f"{cand.median_cell_precision_m:.3g} m above {p:g} m")
    return _report(cand, progress)


def _report(cand: Candidate, progress) -> Candidate:
    if progress is not None:
        keys = ", ".join(f"{k.rsplit('.', 1)[-1]}={v:g}" if isinstance(v, float) else
                         f"{k.rsplit('.', 1)[-1]}={v}" for k, v in cand.overrides.items())
        progress(f"  {keys}: covered {cand.fraction_covered:.3f}, flight "
                 f"{cand.flight_time_s:.0f} s" + ("" if cand.feasible else
                                                   f" ({'; '.join(cand.shortfalls)})"))
    return cand


def _coverage_ok(c: Candidate, req: Requirement) -> bool:
    """The spacing-dependent part of the requirement (bisection's predicate)."""
    p = req.max_height_precision_m
    return c.fraction_covered >= req.min_covered and (
        p is None or c.median_cell_precision_m <= p)


def _search_lines(evaluate, key: str, combo: dict, req: Requirement,
                  extent_m: float) -> list[Candidate]:
    """Candidates of one combination (module docstring): the number of lines n, spacing
    extent / n (rounded up to the millimetre, so the lawnmower lays exactly n), from the count
    that puts lines one cell apart, halved or doubled until the requirement flips, then
    bisected to the fewest lines that meet it."""
    seen: list[Candidate] = []
    n_max = max(1, math.ceil(extent_m / (req.cell_m / 8)))   # denser adds nothing to a cell

    def ok(n: int) -> bool:
        c = evaluate({**combo, key: math.ceil(extent_m / n * 1000.0) / 1000.0})
        seen.append(c)
        return _coverage_ok(c, req)

    n = max(1, math.ceil(extent_m / req.cell_m - 1e-9))
    if ok(n):
        lo, hi = None, n                  # lo: a count that fails, hi: one that meets it
        while lo is None and hi > 1 and len(seen) < MAX_EVALUATIONS:
            if ok(hi // 2):
                hi //= 2
            else:
                lo = hi // 2
        if lo is None:
            return seen                   # one line meets it
    else:
        lo, hi = n, None
        while hi is None and lo < n_max and len(seen) < MAX_EVALUATIONS:
            if ok(min(2 * lo, n_max)):
                hi = min(2 * lo, n_max)
            else:
                lo = min(2 * lo, n_max)
        if hi is None:
            return seen                   # not even the densest lines meet it
    while hi - lo > 1 and len(seen) < MAX_EVALUATIONS:
        mid = (lo + hi) // 2
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return seen


def _extent_across(config) -> float:
    """Width [m] of the survey polygon across its lines (what the lawnmower's lines share)."""
    from ..geometry.paths import lawnmower_width

    _, sec = _lawnmower_section(config)
    return lawnmower_width(sec.survey_polygon_m, math.radians(sec.heading_deg))


def find_plan(mission, req: Requirement, *, vary=(), overrides=(), workers=None,
              progress=None, workdir=None) -> PlanResult:
    """Search the plan (module docstring). ``vary``: ``KEY=START:STOP:N`` or ``KEY=V1,V2,...``
    specs of up to two keys (altitude, speed, heading, ...); ``overrides``: ``--set`` texts."""
    from ..config.loader import load_mission

    mission = Path(mission)
    config = load_mission(mission, list(overrides))
    kind, sec = _lawnmower_section(config)
    key = f"platform.{kind}.line_spacing_m"
    axes = [parse_vary(v) for v in vary]
    if len(axes) > 2:
        raise ConfigError("--vary: at most two keys (with the line spacing the plan chooses)")
    set_keys = {resolve_key(parse_set(t)[0]) for t in overrides}
    if key in set_keys:
        raise ConfigError(f"--set {key}: plan chooses the line spacing itself")
    for a in axes:
        if a.mission_key == key:
            raise ConfigError(f"--vary {a.spec}: plan chooses {key} itself")
        if a.mission_key in set_keys:
            raise ConfigError(f"--vary {a.spec}: {a.mission_key} is also given with --set")
    combos = [dict(zip([a.mission_key for a in axes], vals))
              for vals in itertools.product(*[a.values for a in axes])] or [{}]
    endurance = sec.endurance_s
    cands: list[Candidate] = []
    for combo in combos:
        if progress is not None and combo:
            progress(f"plan: {', '.join(f'{k}={v}' for k, v in combo.items())}")
        with_combo = load_mission(mission, list(overrides) + [f"{k}={toml_literal(v)}"
                                                              for k, v in combo.items()])
        width = _extent_across(with_combo)
        if req.cell_m > width:
            raise ConfigError(f"--cell-m {req.cell_m:g}: wider than the survey polygon across "
                              f"its lines ({width:.0f} m)")

        def evaluate(over):
            return _evaluate(mission, overrides, over, req, endurance, workdir, workers,
                             progress)

        cands += _search_lines(evaluate, key, combo, req, width)
    feasible = [c for c in cands if c.feasible]
    # the quickest; among equally quick ones, the best covered (then the finest precision)
    best = min(feasible, key=lambda c: (c.flight_time_s, -c.fraction_covered,
                                        c.median_cell_precision_m)) if feasible else None
    closest = max(cands, key=lambda c: (c.fraction_covered, -c.flight_time_s))
    return PlanResult(mission, req, list(overrides), cands, best, closest, kind, endurance)


# ------------------------------------------------------------------------------------ output
def _waypoints(path, epsg: int) -> np.ndarray:
    """(m, 3) lon, lat, ellipsoidal height of waypoints that follow the simulated flight: the
    path sampled every WAYPOINT_STEP_S, thinned (Douglas-Peucker, WAYPOINT_TOLERANCE_M) across
    track and, separately, in height; the union of both sets of vertices, first and last kept."""
    from shapely.geometry import LineString

    from ..geometry import frames

    t = np.union1d(np.arange(0.0, path.duration_s, WAYPOINT_STEP_S), [path.duration_s])
    pos = path.positions(t)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1))])
    keep = np.zeros(t.size, bool)
    keep[[0, -1]] = True
    for line in (pos[:, :2], np.column_stack([s, pos[:, 2]])):   # across track, in height
        thin = np.asarray(LineString(line).simplify(WAYPOINT_TOLERANCE_M,
                                                   preserve_topology=False).coords)
        keep[_vertex_indices(line, thin)] = True
    xy, z = pos[keep, :2], pos[keep, 2]
    lat, lon, _ = frames.projected_to_geodetic(xy[:, 0], xy[:, 1], np.zeros(len(xy)), epsg)
    return np.column_stack([lon, lat, z])


def _vertex_indices(line: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Indices in ``line`` of the vertices ``kept`` (shapely's simplify keeps a subsequence of
    them, in order)."""
    out, j = np.empty(len(kept), int), 0
    for k, v in enumerate(kept):          # one pass: the kept vertices come in line order
        while j < len(line) - 1 and not np.array_equal(line[j], v):
            j += 1
        out[k] = j
    return out


def _lines_lonlat(config, scene, kind: str, epsg: int) -> list:
    from ..geometry import frames
    from ..geometry.paths import lawnmower_lines
    from ..mission.survey import survey_polygon_xy

    _, sec = _lawnmower_section(config)
    lines = lawnmower_lines(survey_polygon_xy(config, scene), sec.line_spacing_m,
                            math.radians(sec.heading_deg))
    out = []
    for a, b in lines:
        lat, lon, _ = frames.projected_to_geodetic(np.array([a[0], b[0]]), np.array([a[1], b[1]]),
                                                   np.zeros(2), epsg)
        out.append(np.column_stack([lon, lat]))
    return out


def write_plan(result: PlanResult, out_dir, *, overwrite: bool = False) -> dict:
    """Write mission.toml, plan.geojson, mission.plan and plan.json into ``out_dir``; returns
    the paths. FileExistsError (before writing anything) if any exists without ``overwrite``."""
    from ..mission.flightplan import write_geojson, write_qgc_plan
    from ..mission.preflight import prepare

    out_dir = Path(out_dir)
    names = {"mission": "mission.toml", "geojson": "plan.geojson", "qgc": "mission.plan",
             "json": "plan.json"}
    paths = {k: out_dir / v for k, v in names.items()}
    clash = [str(p) for p in paths.values() if p.exists()]
    if clash and not overwrite:
        raise FileExistsError(f"{', '.join(clash)} exist(s); use --overwrite to replace")
    out_dir.mkdir(parents=True, exist_ok=True)
    chosen = result.chosen
    sets = list(result.base_overrides) + [f"{k}={toml_literal(v)}"
                                          for k, v in chosen.overrides.items()]
    rel = os.path.relpath(result.mission.resolve(), out_dir.resolve())
    lines = [f"# chirplidar plan: {result.mission.name} with the chosen keys "
             f"({'meets' if result.best else 'does NOT meet'} the requirement; plan.json)",
             f"extends = {json.dumps(Path(rel).as_posix())}", ""]
    keys = {}                        # dotted TOML keys: the project's names, TOML literals
    for text in sets:
        key, value = parse_set(text)
        keys[resolve_key(key)] = value
    lines += [f"{k} = {toml_literal(v)}" for k, v in keys.items()]
    paths["mission"].write_text("\n".join(lines) + "\n")
    config, scene, plan = prepare(paths["mission"])
    wp = _waypoints(plan.path, scene.epsg)
    lat0, lon0 = wp[0, 1], wp[0, 0]
    home = np.array([lon0, lat0, float(scene.ground_height_m(*plan.path.positions(
        np.zeros(1))[0, :2]))])
    if not np.isfinite(home[2]):
        home[2] = float(np.mean(scene.height_range_m))
    _, sec = _lawnmower_section(config)
    summary = plan_summary(result)
    write_geojson(paths["geojson"], _lines_lonlat(config, scene, result.kind, scene.epsg), wp,
                  {"mission": result.mission.name, "line_spacing_m": chosen.line_spacing_m,
                   "flight_time_s": chosen.flight_time_s,
                   "fraction_covered": chosen.fraction_covered,
                   "meets_requirement": result.best is not None,
                   "height_datum": "WGS-84 ellipsoid"})
    write_qgc_plan(paths["qgc"], wp, home, cruise_speed_mps=sec.speed_mps,
                   vehicle_type="fixed_wing")
    paths["json"].write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    return paths


def _num(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def plan_summary(result: PlanResult) -> dict:
    """The JSON report: requirement, the chosen plan, whether it meets the requirement, every
    candidate."""
    def cand(c: Candidate) -> dict:
        d = asdict(c)
        return {k: _num(v) for k, v in d.items()} | {"feasible": c.feasible}

    return {"mission": str(result.mission), "requirement": asdict(result.requirement),
            "meets_requirement": result.best is not None, "chosen": cand(result.chosen),
            "endurance_s": result.endurance_s, "candidates": [cand(c) for c in result.candidates]}


def format_plan(result: PlanResult) -> str:
    c, req = result.chosen, result.requirement
    keys = ", ".join(f"{k} = {v}" for k, v in c.overrides.items())
    head = ("chirplidar plan: requirement met" if result.best is not None else
            "chirplidar plan: the requirement cannot be met; the best plan found achieves")
    lines = [f"{head} ({len(result.candidates)} runs)",
             f"  keys             {keys}",
             f"  covered          {c.fraction_covered:.3f} of the {req.cell_m:g} m cells "
             f"(>= {req.min_detections} detection(s); required {req.min_covered:g})",
             f"  height precision {c.median_cell_precision_m:.3g} m for a cell's mean height "
             f"(median over the covered cells)"
             + ("" if req.max_height_precision_m is None
                else f"; required <= {req.max_height_precision_m:g} m"),
             f"  flight time      {c.flight_time_s:.0f} s"
             + ("" if result.endurance_s is None else f" (endurance {result.endurance_s:g} s)")]
    if c.profile is not None:
        p = c.profile
        lines.append(f"  terrain profile  {p['min_clearance_m']:.0f}-{p['max_clearance_m']:.0f} "
                     f"m above ground, climbs <= {p['max_climb_mps']:.2g} m/s, descents <= "
                     f"{p['max_descent_mps']:.2g} m/s")
    if result.best is None:
        lines.append(f"  short of it      {'; '.join(c.shortfalls)}")
    return "\n".join(lines)
