"""Command line ``chirplidar``: ``shot``, ``sweep``, ``run``, ``coverage``, ``view``, ``study``,
``plan``, ``passes``, ``bench`` and ``demo``.

Exit codes: 0 success, 1 a run finished but a requested product could not be made (e.g. no
spectrum to plot), or ``run`` stopped by another fault (e.g. its Dask scheduler lost), 2 bad input
(configuration error, unknown name, bad option, an unreadable input or unwritable output folder),
74 a file could not be written (disk full, permission denied, I/O error), 130 interrupted.
Configuration errors and faults are printed to stderr in one line, without a traceback
(``CHIRPLIDAR_DEBUG=1`` prints it too).

JSON output has no infinities: a non-finite number is written as ``null``. For the dB outputs
(dBm, dBm/Hz, dB) ``null`` means -inf dB, i.e. zero power (e.g. ``Psig`` with no return).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import warnings
from pathlib import Path
from typing import Any, Sequence

TIERS = ("rf", "link")
JSON_NOTE = ("JSON has no infinities: non-finite numbers are written as null; for dB quantities "
             "null means -inf dB (zero power).")


class UsageError(Exception):
    """Bad command-line input detected after parsing (exit code 2)."""


# ---------------------------------------------------------------------------------------- helpers

def _json_number(value: Any) -> Any:
    """A JSON-safe value: non-finite floats become None (null); numpy scalars become Python."""
    if value is None or isinstance(value, (bool, str, int)):
        return value
    try:
        f = float(value)
    except (TypeError, ValueError):
        return value
    return f if math.isfinite(f) else None


def _dump_json(obj: Any) -> str:
    return json.dumps(obj, allow_nan=False, indent=None)


def _shot_record(result: dict, names: Sequence[str]) -> dict:
    """The JSON object of one shot: Table 4.10 names, flags, tier, f_beat_hz."""
    rec = {n: _json_number(result[n]) for n in names}
    rec["flags"] = [str(f) for f in result.get("flags", [])]
    rec["tier"] = str(result.get("tier", ""))
    rec["f_beat_hz"] = _json_number(result.get("f_beat_hz", math.nan))
    return rec


def _fmt_value(value: float) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "nan"
    if math.isinf(value):
        return "-inf" if value < 0 else "inf"
    return f"{value:.6g}"


def _resolve_output_name(name: str, valid: Sequence[str], *, allow_x: str | None = None) -> str:
    """Table 4.10 name for ``name`` (``outputs.CNR`` -> ``SNR``); ``x`` or the varied key allowed."""
    from .config import resolve_output

    if allow_x is not None and name in ("x", allow_x):
        return "x"
    resolved = resolve_output(name)
    if resolved not in valid:
        extra = f"x (the varied {allow_x}), " if allow_x else ""
        raise UsageError(f"unknown output name '{name}'; valid names: {extra}{', '.join(valid)} "
                         "(thesis 'outputs.NAME' and 'outputs.CNR' accepted)")
    return resolved


def _sweep_flags(ds, n_x: int) -> list[list[str]] | None:
    """Per-x flag lists from the sweep's comma-separated ``flags`` variable, if it has one."""
    if "flags" not in ds.data_vars:
        return None
    raw = [str(v) for v in ds["flags"].values.reshape(n_x, -1)[:, 0]]
    return [[f for f in v.split(",") if f] for v in raw]


def _load(args) -> Any:
    """The mission's configuration with ``--set``; ``--at-s`` and ``--beam`` (which pick a shot
    of a survey) are refused on a mission without a ``[survey]`` section."""
    from .config import load_mission

    cfg = load_mission(args.mission, args.set or [])
    given = [o for o, v in (("--at-s", getattr(args, "at_s", None)),
                            ("--beam", getattr(args, "beam", None))) if v is not None]
    if given and cfg.survey is None:
        raise UsageError(f"{' and '.join(given)} pick a shot of a survey mission (a file with "
                         f"[scene], [platform], [attitude], [beams] and [survey]); "
                         f"{args.mission} has no [survey] section")
    return cfg


def _fix_mission_after_set(parser: argparse.ArgumentParser, args) -> None:
    """``--set`` takes several KEY=VALUE; a MISSION written after it lands in args.set: move it."""
    if getattr(args, "mission", "") is None:
        if args.set and "=" not in args.set[-1]:
            args.mission = args.set.pop()
        else:
            parser.error("the following arguments are required: MISSION")


# ---------------------------------------------------------------------------------------- commands

def cmd_shot(args) -> int:
    from .api import OUTPUT_NAMES, OUTPUT_UNITS, simulate_mission_shot, simulate_shot
    from .mission.shot import GEOMETRY_KEYS, is_survey

    cfg = _load(args)
    if is_survey(cfg):
        # A survey mission: one shot of the survey at its own geometry, never the bench channel.
        result = simulate_mission_shot(args.mission, overrides=args.set or [], seed=args.seed,
                                       tier=args.tier, at_s=args.at_s,
                                       beam=0 if args.beam is None else args.beam,
                                       return_spectrum=bool(args.plot))
    else:
        result = simulate_shot(cfg, seed=args.seed, tier=args.tier,
                               return_spectrum=bool(args.plot))
    mission_geometry = bool(result.get("mission_geometry"))
    if args.json:
        rec = _shot_record(result, OUTPUT_NAMES)
        if mission_geometry:
            rec.update({k: _json_number(result[k]) for k in GEOMETRY_KEYS})
            rec["mission_geometry"] = True
        print(_dump_json(rec))
    else:
        print(f"{args.mission}  tier {result.get('tier', args.tier)}"
              + (f"  seed {args.seed}" if args.seed is not None else ""))
        if mission_geometry:
            r = result
            print(f"  survey shot t = {r['t_s']:.6g} s (shot {r['shot_index']}), beam {r['beam']}: "
                  f"range {r['range_m']:.2f} m to {r['surface']} at x {r['x_m']:.1f} m, "
                  f"y {r['y_m']:.1f} m, incidence {r['incidence_deg']:.1f} deg")
        for name in OUTPUT_NAMES:
            print(f"  {name:<9} {_fmt_value(result[name]):>14}  {OUTPUT_UNITS.get(name, '')}")
        f_beat = result.get("f_beat_hz", math.nan)
        print(f"  {'f_beat':<9} {_fmt_value(f_beat / 1e6 if math.isfinite(f_beat) else f_beat):>14}"
              "  MHz")
        flags = result.get("flags", [])
        print(f"  flags     {', '.join(flags) if flags else '(none)'}")
    if args.plot:
        spectrum = result.get("spectrum")
        if spectrum is None:
            print(f"chirplidar shot: tier '{result.get('tier', args.tier)}' returned no spectrum; "
                  "--plot needs --tier rf", file=sys.stderr)
            return 1
        from .viz.spectrum import plot_beat_spectrum

        where = (f", t = {result['t_s']:.6g} s, beam {result['beam']}, "
                 f"{result['range_m']:.1f} m" if mission_geometry else "")
        path = plot_beat_spectrum(spectrum, args.plot, outputs=result, unit=args.plot_unit,
                                  title=f"Dechirped beat spectrum ({args.mission}{where}, "
                                        f"{result.get('tier', args.tier)} tier)")
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_sweep(args) -> int:
    from .api import OUTPUT_NAMES, OUTPUT_UNITS, sweep, sweep_mission
    from .mission.shot import GEOMETRY_KEYS, GEOMETRY_UNITS, is_survey

    if args.n < 1:
        raise UsageError(f"--n must be >= 1, got {args.n}")
    if args.repeat < 1:
        raise UsageError(f"--repeat must be >= 1, got {args.repeat}")
    if args.scale == "log" and (args.start <= 0 or args.stop <= 0):
        raise UsageError(f"--scale log needs positive --start and --stop (got {args.start:g}, "
                         f"{args.stop:g})")
    import numpy as np

    cfg = _load(args)
    survey = is_survey(cfg)
    # A survey sweep can also plot the evaluated shot's geometry (range_m, incidence_deg, ...).
    geometry_names = [k for k in GEOMETRY_KEYS if k in GEOMETRY_UNITS] if survey else []
    plottable = (*OUTPUT_NAMES, "f_beat_hz", *geometry_names)
    x_name = _resolve_output_name(args.x, plottable, allow_x=args.vary)
    y_name = _resolve_output_name(args.y, plottable, allow_x=args.vary)
    # Check the varied key and both end values before any shot runs (no progress bar for a typo).
    from .config import ConfigError, config_with

    for value in (args.start, args.stop):
        try:
            config_with(cfg, {args.vary: value})
        except ConfigError as exc:
            msg = str(exc).removeprefix("--set: ").removeprefix("override: ")
            raise ConfigError(f"--vary {args.vary} at {value:g}: {msg}") from None
    if survey:
        # Each point re-plans the mission with the varied key: the shot at that point's geometry.
        ds = sweep_mission(args.mission, args.vary, args.start, args.stop, args.n,
                           overrides=args.set or [], repeat=args.repeat, scale=args.scale,
                           seed=args.seed, tier=args.tier, at_s=args.at_s,
                           beam=0 if args.beam is None else args.beam,
                           progress=not args.no_progress)
    else:
        ds = sweep(cfg, args.vary, args.start, args.stop, args.n, repeat=args.repeat,
                   scale=args.scale, seed=args.seed, tier=args.tier,
                   progress=not args.no_progress)
    xs = [float(v) for v in ds["x"].values]
    n_rep = int(ds.sizes.get("repeat", 1))
    names = list(OUTPUT_NAMES) + (["f_beat_hz"] if "f_beat_hz" in ds.data_vars else [])
    table = {n: ds[n].transpose("x", ...).values.reshape(len(xs), n_rep) for n in names}
    # Per point, as Python numbers (ints stay JSON integers: beam, shot_index) and strings.
    geometry = {k: ds[k].values.tolist() for k in GEOMETRY_KEYS if survey and k in ds.data_vars}
    for k in geometry_names:  # per point: the same value for every repeat
        table[k] = np.repeat(np.asarray(geometry[k], float)[:, None], n_rep, axis=1)
    flags = _sweep_flags(ds, len(xs))
    if args.json:
        records = []
        for i, xv in enumerate(xs):
            for r in range(n_rep):
                rec = {"x": _json_number(xv), "repeat": r}
                rec.update({n: _json_number(table[n][i, r]) for n in names})
                if flags is not None:
                    rec["flags"] = flags[i]
                if survey:
                    rec.update({k: _json_number(v[i]) for k, v in geometry.items()})
                    rec["mission_geometry"] = True
                records.append(rec)
        print(_dump_json(records))
    else:
        cols = [c for c in dict.fromkeys([x_name, y_name, "Psig", "SNR", "d_rx", "d_error",
                                          *(["range_m"] if survey else [])])
                if c != "x"]
        print(f"sweep of {args.vary} ({args.scale}, {args.n} x {n_rep}), tier {args.tier}")
        if survey:
            surfaces = sorted({str(v) for v in geometry["surface"]})
            beam = int(geometry["beam"][0])
            when = (f"nearest to t = {args.at_s:g} s" if args.at_s is not None
                    else "first shot whose beam hits the terrain")
            print(f"  at the mission's geometry: beam {beam}, {when} (t = "
                  + ", ".join(f"{t:.6g}" for t in sorted(set(geometry['t_s'])))
                  + f" s), surface {', '.join(surfaces)}")
        units = dict(OUTPUT_UNITS, f_beat_hz="Hz", **GEOMETRY_UNITS)
        print(f"  {args.vary:>14} {'repeat':>6} "
              + " ".join(f"{c + ' (' + units.get(c, '') + ')':>15}" for c in cols)
              + ("  flags" if flags is not None else ""))
        for i, xv in enumerate(xs):
            for r in range(n_rep):
                print(f"  {xv:>14.6g} {r:>6d} "
                      + " ".join(f"{_fmt_value(float(table[c][i, r])):>15}" for c in cols)
                      + (f"  {','.join(flags[i])}" if flags is not None and flags[i] else ""))
    if args.plot:
        from .viz.sensitivity import plot_sweep

        plot_ds = ds
        for k in {x_name, y_name} & set(geometry_names):  # dims (x,) -> (x, repeat) to plot
            plot_ds = plot_ds.assign({k: (("x", "repeat"), table[k], dict(ds[k].attrs))})
        path = plot_sweep(plot_ds, args.plot, x=x_name, y=y_name, x_scale=args.scale)
        print(f"wrote {path}", file=sys.stderr)
    return 0


def _check_cluster_args(args) -> None:
    """``--workers`` / ``--scheduler`` of ``run`` and ``study``."""
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler is not None:
        raise UsageError("--workers and --scheduler are exclusive: --workers N starts a local "
                         "cluster, --scheduler ADDRESS uses a running one")
    if args.scheduler is not None and not args.scheduler.strip():
        raise UsageError("--scheduler needs an address, e.g. tcp://127.0.0.1:8786")


def cmd_run(args) -> int:
    from .mission.runner import run_mission
    from .mission.summary import format_summary

    _check_cluster_args(args)
    if args.dry_run:
        return _dry_run(args)
    try:
        result = run_mission(args.mission, overrides=args.set or [], tier=args.tier, out=args.out,
                             seed=args.seed, overwrite=args.overwrite,
                             progress=not args.no_progress, workers=args.workers,
                             scheduler=args.scheduler, resume=args.resume, yes=args.yes)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(_dump_json({k: _json_number(v) for k, v in result.summary.items()}))
    else:
        print(format_summary(result.summary))
    return 0


def _dry_run(args) -> int:
    """``run --dry-run``: the checks, warnings and size of the run; nothing is written."""
    from .mission import preflight
    from .mission.runner import check_output, default_output, preflight_run

    notes = []
    try:
        out = check_output(args.out, args.mission, overwrite=args.overwrite)
    except FileExistsError:   # the run would refuse it; the plan is still worth seeing
        out = check_output(args.out, args.mission, overwrite=True)
        notes.append(f"{out} exists: the run needs --overwrite to replace it")
    if not out.parent.is_dir() and out != default_output(args.mission):
        raise UsageError(f"--out {out}: directory {out.parent} does not exist")
    with warnings.catch_warnings():   # the report lists them
        warnings.simplefilter("ignore", preflight.PlannerWarning)
        config, scene, plan, planner_warnings, estimate = preflight_run(
            args.mission, overrides=args.set or [], tier=args.tier, seed=args.seed,
            cores=args.workers or 1)
    report = {"mission": str(args.mission), "tier": config.survey.tier,
              "platform": config.platform.kind, "scene": str(scene.path), **estimate.as_dict(),
              "large": estimate.large,
              "planner_warnings": [*planner_warnings, *notes]}
    if args.json:
        print(_dump_json({k: _json_number(v) for k, v in report.items()}))
    else:
        print(f"{args.mission}: {config.survey.tier} tier, {config.platform.kind} over "
              f"{Path(scene.path).name}")
        print(f"  {preflight.format_estimate(estimate)}")
        if estimate.large:
            print("  a large run: `chirplidar run` needs --yes to start it")
        for text in report["planner_warnings"]:
            print(f"  warning: {text}")
    return 0


#: Summary figures shown on the coverage map: its label (the map's box formats by the suffix)
#: and the summary's key.
_MAP_SUMMARY = {"fraction_covered": "fraction_covered", "cells_covered": "cells_covered",
                "cells_in_region": "cells_in_region", "largest_gap_m": "largest_gap_m",
                "median_height_error_of_a_shot_m": "median_height_precision_m",
                "along_track_spacing_m": "along_track_spacing_m",
                "across_track_spacing_m": "across_track_spacing_m",
                "crossovers": "crossovers", "crossover_rms_m": "crossover_rms_m"}


def _output_path(option: str, value, suffix: str, *, overwrite: bool | None) -> Path:
    """An output file named on the command line, checked before any work
    (:func:`chirplidar._checks.writable_file`) and, unless ``overwrite`` is None (a picture is
    replaced), refused when it exists without ``--overwrite``."""
    from . import _checks

    try:
        path = _checks.writable_file(option, value, suffix)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if overwrite is not None and path.exists() and not overwrite:
        raise UsageError(f"{option} {path} exists: pass --overwrite to replace it "
                         "(nothing was computed)")
    return path


def cmd_coverage(args) -> int:
    from .analysis.coverage import (EDGE_WARNING, GRID_VARIABLES, compute_coverage,
                                    summary_json, write_coverage)

    out = png = None
    if args.out is not None:
        out = _output_path("--out", args.out, ".nc", overwrite=args.overwrite)
    if args.png is not None:
        png = _output_path("--png", args.png, ".png", overwrite=None)   # a picture: replaced
    if args.var not in GRID_VARIABLES:
        raise UsageError(f"--var {args.var}: not a coverage grid variable; choose one of "
                         f"{', '.join(GRID_VARIABLES)}")
    bounds = None
    if args.bounds is not None:
        from .mission.view import parse_bounds

        try:
            bounds = parse_bounds(args.bounds)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    try:
        cov = compute_coverage(args.results, cell_m=args.cell_m, region=args.region,
                               bounds=bounds, min_detections=args.min_detections,
                               progress=not args.no_progress)
    except ValueError as exc:   # CoverageError: one line naming the file or option
        raise UsageError(str(exc)) from None
    edge = cov.summary["footprints_on_cell_edges"]
    if edge > EDGE_WARNING:
        warnings.warn(f"{100 * edge:.0f} % of the footprints lie within 1 % of a cell width of "
                      "a cell edge (tracks along grid lines): they count in the cells on both "
                      "sides; shift the grid (--bounds) or change --cell-m to see the "
                      "coverage of a grid not aligned with the tracks")
    try:   # the map first: a map that cannot be written leaves no grid file behind
        if png is not None:
            print(f"wrote {_coverage_map(cov, args, png)}", file=sys.stderr)
        if out is not None:
            print(f"wrote {write_coverage(cov, out, overwrite=args.overwrite)}", file=sys.stderr)
    except OSError as exc:
        raise UsageError(f"cannot write {exc.filename or ''}: {exc.strerror or exc}") from None
    if args.json:
        print(summary_json(cov.summary))
    else:
        print(format_coverage_summary(cov.summary))
    return 0


def _coverage_map(cov, args, png):
    """The plan-view map of a coverage result (hillshade of the first file's scene)."""
    import xarray as xr

    from .mission.view import result_terrain
    from .viz.planmap import plot_plan_map

    with xr.open_dataset(args.results[0], decode_times=False) as ds:   # attributes only
        terrain = result_terrain(ds)
    s = cov.summary
    names = ", ".join(Path(p).name for p in args.results)
    title = (f"Coverage of {names}: {cov.grid[args.var].attrs['long_name']}, "
             f"{s['cell_m']:g} m cells")
    region = s["region"]
    label = {"survey": "survey polygon", "scene": "scene extent", "bounds": "--bounds box",
             "footprints": "footprints' extent"}.get(region["kind"],
                                                     Path(region.get("file", "")).name)
    grid = cov.grid
    if args.var in ("shots", "detected_shots", "tracks"):   # cells no footprint fell in: clear,
        grid = grid.copy()                                   # the terrain shows through
        grid[args.var] = grid[args.var].where(grid["shots"] > 0)
    return plot_plan_map(png, terrain=terrain, tracks=list(cov.tracks), grid=grid,
                         var=args.var, region=cov.region, region_label=f"region: {label}",
                         crossovers=cov.crossovers,
                         summary={label: s[k] for label, k in _MAP_SUMMARY.items()},
                         title=title, epsg=cov.epsg)


def format_coverage_summary(s: dict) -> str:
    def m(v):
        if v is None or not math.isfinite(v):
            return "n/a"
        return f"{v / 1e3:.3g} km" if abs(v) >= 1e4 else f"{v:.3g} m" if abs(v) < 1e3 \
            else f"{v:.0f} m"

    region = s["region"]
    where = region.get("file", region["kind"])
    lines = [
        f"chirplidar coverage: {len(s['files'])} file(s), {s['shots']} shots with a surface "
        f"in the beam ({s['detected_shots']} detected), cells of {s['cell_m']:g} m, region {where} "
        f"(EPSG:{region['epsg']})",
        f"  covered          {s['cells_covered']} of {s['cells_in_region']} cells "
        f"({100 * s['fraction_covered']:.1f} %) with >= {s['min_detections']} detection(s)",
        f"  largest gap      {m(s['largest_gap_m'])} (to the nearest detected footprint)",
        f"  detections/cell  median {s['median_detections_per_cell']:g}",
        f"  height precision median {m(s['median_height_precision_m'])} per shot measured, "
        f"{m(s['median_height_precision_predicted_m'])} predicted",
        f"  spacing          {m(s['along_track_spacing_m'])} along track, "
        f"{m(s['across_track_spacing_m'])} across",
        f"  flown            {s['track_length_m'] / 1e3:.2f} km in {s['flight_time_s']:.0f} s",
        f"  crossovers       {s['crossovers']}"
        + (f", RMS height residual {m(s['crossover_rms_m'])}" if s["crossovers"] else ""),
    ]
    if s["cells_revisited"]:
        lines.append(f"  revisits         {s['cells_revisited']} cells seen by two or more "
                     f"tracks, median interval {_duration(s['median_revisit_s'])}")
    return "\n".join(lines)


def _duration(seconds: float) -> str:
    """Seconds as s, min, h or days, whichever reads best."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.0f} s"


def cmd_view(args) -> int:
    from .mission.view import parse_bounds, view_plan, view_result

    camera = {"--camera-azimuth": args.camera_azimuth, "--camera-elevation":
              args.camera_elevation, "--zoom": args.zoom}
    try:
        bounds = parse_bounds(args.bounds) if args.bounds is not None else None
        if args.plan:
            if args.png is None:
                raise UsageError("--plan writes a file: give --png OUT.png")
            given = [name for name, value in camera.items() if value is not None]
            if given:
                raise UsageError(f"{', '.join(given)}: only for the 3-D view, not with --plan")
            path = view_plan(args.result, var=args.var, png=args.png, bounds=bounds)
        else:
            path = view_result(args.result, var=args.var, png=args.png, bounds=bounds,
                               camera_azimuth_deg=args.camera_azimuth,
                               camera_elevation_deg=args.camera_elevation, zoom=args.zoom)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if path is not None:
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_plan(args) -> int:
    from .analysis.plan import Requirement, find_plan, format_plan, plan_summary, write_plan

    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"--out {out_dir}: exists and is not a folder")
    clash = [out_dir / n for n in ("mission.toml", "plan.geojson", "mission.plan", "plan.json")
             if (out_dir / n).exists()]
    if clash and not args.overwrite:
        raise UsageError(f"--out {out_dir}: {clash[0].name} exists: pass --overwrite to replace "
                         "the plan (nothing was computed)")
    if not Path(args.mission).is_file():
        raise UsageError(f"{args.mission}: mission file does not exist")
    req = Requirement(args.cell_m, args.min_covered, args.min_detections,
                      args.max_height_precision_m)
    say = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
    result = find_plan(args.mission, req, vary=args.vary, overrides=args.set or [],
                       workers=args.workers, progress=say)
    try:
        paths = write_plan(result, out_dir, overwrite=args.overwrite)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(_dump_json(plan_summary(result) | {"files": {k: str(v) for k, v in paths.items()}}))
    else:
        print(format_plan(result))
        print(f"  wrote            {', '.join(str(p) for p in paths.values())}")
    return 0 if result.best is not None else 1


def cmd_study(args) -> int:
    """``chirplidar study``: the survey mission at every point of a grid of one or two keys
    (:mod:`chirplidar.analysis.study`); a table, JSON, a plot and/or a NetCDF study file."""
    from .analysis.study import check_output_file, run_study
    from .analysis.study_output import format_study, study_records

    if not args.vary:
        raise UsageError("--vary KEY=START:STOP:N or KEY=V1,V2,... is required")
    _check_cluster_args(args)
    if args.plot is not None and not args.plot.lower().endswith(".png"):
        raise UsageError(f"--plot {args.plot}: the plot file must end in .png")
    if args.plot is not None:   # before any point runs (--out: run_study checks it)
        check_output_file("--plot", args.plot, ".png", make_parents=True)
    plot_error: list[OSError] = []

    def plot_first(ds) -> bool:
        # the plot before the study file: a plot that cannot be saved leaves no study file
        from .viz.study import plot_study

        existed = Path(args.plot).exists()
        try:
            plot_study(ds, args.plot)
        except OSError as exc:
            plot_error.append(exc)
            if not existed:
                Path(args.plot).unlink(missing_ok=True)   # no partial PNG either
            return False
        return True

    try:
        ds = run_study(args.mission, args.vary, overrides=args.set or [], span_s=args.span_s,
                       cell_m=args.cell_m, tier=args.tier, seed=args.seed,
                       workers=args.workers, scheduler=args.scheduler,
                       progress=not args.no_progress, out=args.out, overwrite=args.overwrite,
                       before_write=plot_first if args.plot else None)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:   # e.g. the study file on a full disk: one line, no traceback
        raise UsageError(str(exc)) from None
    if args.json:
        print(_dump_json([{k: _json_number(v) for k, v in rec.items()}
                          for rec in study_records(ds)]))
    else:
        print(format_study(ds))
    if plot_error:
        exc = plot_error[0]
        kept = f"; the study file {args.out} was not written" if args.out is not None else ""
        print(f"chirplidar study: error: --plot {args.plot}: cannot save the plot "
              f"({exc.strerror or exc}){kept}", file=sys.stderr)
        return 1
    if args.plot:
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.out is not None:
        print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _bench_accuracy_or_tiers(args) -> int:
    """``bench --what tiers`` (seconds per shot of rf, baseband, link) and ``--what accuracy``
    (the accuracy-versus-time study, written to accuracy_vs_time.{csv,md,png} in --out)."""
    if args.what == "tiers":
        from .bench import bench_tiers

        res = bench_tiers(args.mission, args.set or [], repeats=max(1, min(args.repeats, 5)))
        if args.json:
            print(_dump_json(res))
        else:
            print(f"seconds per shot ({args.mission or 'missions/thesis_bench.toml'}), median of "
                  f"{max(1, min(args.repeats, 5))} rounds:")
            print(f"  rf        {res['rf_shot_s'] * 1e3:10.3f} ms   (one shot per call)")
            print(f"  baseband  {res['baseband_shot_s'] * 1e3:10.3f} ms   (256 shots per call; "
                  f"x{res['baseband_speedup']:.1f} faster than rf)")
            print(f"  link      {res['link_shot_s'] * 1e6:10.3f} us   (1,000,000 shots per call; "
                  f"{res['link_shots_per_s']:.3g} shots/s)")
        return 0
    from .analysis.accuracy import run_accuracy_bench

    if args.shots is not None and args.shots < 2:
        raise UsageError(f"--shots must be >= 2, got {args.shots}")
    kwargs = {} if args.shots is None else {"shots": args.shots}
    say = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
    try:
        rows, paths, elapsed = run_accuracy_bench(args.out, args.mission, args.set or [],
                                                  progress=say, **kwargs)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(_dump_json({"elapsed_s": elapsed, "files": {k: str(v) for k, v in paths.items()},
                          "rows": [{k: _json_number(v) for k, v in r.items()} for r in rows]}))
    else:
        print(paths["md"].read_text())
        for path in paths.values():
            print(f"wrote {path}", file=sys.stderr)
        print(f"study wall time {elapsed:.0f} s", file=sys.stderr)
    return 0


def cmd_bench(args) -> int:
    from .bench import bench_effects, bench_shot

    if args.repeats < 1:
        raise UsageError(f"--repeats must be >= 1, got {args.repeats}")
    if args.what in ("accuracy", "tiers"):
        return _bench_accuracy_or_tiers(args)
    if args.what == "raycast":
        from .geometry import bench_raycast

        res = bench_raycast(args.triangles, args.rays, repeats=max(1, min(args.repeats, 5)))
        if args.json:
            print(_dump_json({k: res[k] for k in ("project_rays_per_s", "embree_rays_per_s", "ratio")}))
        else:
            print(f"ray casting, {res['n_triangles']} triangles, {res['n_rays']} rays "
                  f"(scene build {res['build_s']:.2f} s, not timed):")
            print(f"  chirplidar cast_rays  {res['project_rays_per_s']:.3g} rays/s")
            print(f"  raw embree            {res['embree_rays_per_s']:.3g} rays/s")
            print(f"  ratio                 {res['ratio']:.2f}  (goal >= 0.7)")
        return 0
    if args.what == "scale":
        from .mission.scale_bench import bench_scale, format_scale

        say = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
        res = bench_scale(args.mission, args.set or [], repeats=args.repeats, progress=say)
        if args.json:
            print(_dump_json({k: res[k] for k in ("serial_s", "workers_2_s", "speedup")}))
        else:
            print(format_scale(res))
        return 0
    if args.what == "campaign":
        from .mission.scale_bench import bench_campaign, format_campaign

        say = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
        try:
            res = bench_campaign(args.mission, args.set or [], workers=args.workers,
                                 progress=say)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if args.json:
            print(_dump_json({k: _json_number(res[k]) for k in ("days", "passes", "shots",
                                                              "seconds", "shots_per_s")}))
        else:
            print(format_campaign(res))
        return 0
    if args.what == "coverage":
        from .analysis.coverage_bench import bench_coverage, format_coverage_bench

        if args.shots is not None and args.shots < 1000:
            raise UsageError(f"--shots must be >= 1000 for --what coverage, got {args.shots}")
        say = None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
        res = bench_coverage(10_000_000 if args.shots is None else args.shots, progress=say)
        if args.json:
            print(_dump_json({k: (res[k] if k == "sizes" else _json_number(res[k]))
                              for k in ("shots", "seconds", "shots_per_s", "peak_memory_mb",
                                        "baseline_memory_mb", "sizes")}))
        else:
            print(format_coverage_bench(res))
        return 0
    if args.what == "effects":
        res = bench_effects(args.mission, args.set or [], repeats=args.repeats)
        if args.json:
            print(_dump_json(res))
        else:
            base = res["none_s"]
            print(f"seconds per rf shot ({args.mission or 'missions/thesis_bench.toml'}), "
                  f"median of {args.repeats}:")
            for key, value in res.items():
                print(f"  {key[:-2]:<12} {value * 1e3:8.2f} ms   x{value / base:.2f}")
        return 0
    res = bench_shot(args.mission, args.set or [], repeats=args.repeats)
    if args.json:
        print(_dump_json({k: res[k] for k in ("rf_shot_s", "fft_s", "ratio")}))
    else:
        print(f"rf shot ({args.mission or 'missions/thesis_bench.toml'}): "
              f"{res['rf_shot_s'] * 1e3:.2f} ms")
        print(f"one rfft of N = {res['n_samples']} samples: {res['fft_s'] * 1e3:.3f} ms")
        print(f"ratio shot / FFT: {res['ratio']:.1f}  (median of {args.repeats} shot/FFT pairs, after warm-up)")
    return 0


#: Longest window of ``chirplidar passes`` (a TLE is refused beyond 120 days of its epoch).
PASSES_MAX_DAYS = 366.0


def cmd_passes(args) -> int:
    from .analysis.passes import (find_passes, format_passes, orbit_from_mission,
                                  orbit_from_tle_file, passes_report, region_from_geojson,
                                  region_from_scene)
    from .config import ConfigError
    from .geometry.earth_orientation import parse_utc, utc_iso

    if (args.mission is None) == (args.tle is None):
        raise UsageError("give a satellite MISSION file or --tle FILE (one of them)")
    png = None if args.png is None else _output_path("--png", args.png, ".png", overwrite=None)
    try:
        start = parse_utc(args.start, "--start")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not (math.isfinite(args.days) and 0 < args.days <= PASSES_MAX_DAYS):
        raise UsageError(f"--days must be > 0 and <= {PASSES_MAX_DAYS:g}, got {args.days:g}")
    if args.tle is not None:
        if args.region is None:
            raise UsageError("--region is required with --tle (a scene .toml or a GeoJSON "
                             "polygon)")
        try:
            source = orbit_from_tle_file(args.tle, utc_iso(start))
        except ValueError as exc:
            raise UsageError(f"--tle {exc}") from None
    else:
        source = orbit_from_mission(args.mission, utc_iso(start))
    try:
        if args.region is None:
            if source.scene_file is None:
                raise UsageError(f"{args.mission} has no [scene]: give --region")
            region = region_from_scene(source.scene_file, source.scene_overrides)
        else:
            where = Path(args.region)
            if not where.is_file():
                raise UsageError(f"--region {where}: file does not exist")
            if where.suffix.lower() == ".toml":
                region = region_from_scene(where)
            elif where.suffix.lower() in (".geojson", ".json"):
                region = region_from_geojson(where)
            else:
                raise UsageError(f"--region {where}: expected a scene .toml or a .geojson "
                                 "polygon")
    except ConfigError:
        raise
    except ValueError as exc:
        raise UsageError(f"--region {exc}") from None
    try:
        passes = find_passes(source.orbit, region, start, args.days, beams=source.beams,
                             attitude=source.attitude, region_height_m=region.height_m,
                             doppler_steering=source.doppler_steering, progress=sys.stderr.isatty() and not args.no_progress)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    report = passes_report(passes, region, source, start, args.days)
    if png is not None:
        from .viz.passes import plot_passes

        w = report["window"]
        try:
            path = plot_passes(passes, region, png, window=(w["start_utc"], w["end_utc"]),
                               satellite=source.name)
        except OSError as exc:
            raise UsageError(f"cannot write {exc.filename or png}: "
                             f"{exc.strerror or exc}") from None
        print(f"wrote {path}", file=sys.stderr)
    if not passes:
        w = report["window"]
        print(f"chirplidar passes: no pass of {source.name} over {region.name} between "
              f"{w['start_utc']} and {w['end_utc']}", file=sys.stderr)
    if args.json:
        print(_dump_json(report))
    elif passes:
        print(format_passes(report))
    return 0


def cmd_demo(args) -> int:
    from .demo import format_summary, run_demo

    result = run_demo(args.out, tier=args.tier, points=args.points, mission=args.mission,
                      seed=args.seed, progress=not args.no_progress)
    print(format_summary(result))
    return 0


# ---------------------------------------------------------------------------------------- parser

def _add_common(p: argparse.ArgumentParser, *, mission_positional: bool = True) -> None:
    if mission_positional:
        p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                       help="mission TOML file, e.g. missions/thesis_bench.toml")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key (thesis names accepted: chrp.F2=300e6, "
                        "sys.rsel=PIN, atm.Pattn=40); repeatable")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed (default: the mission's seed)")
    p.add_argument("--tier", choices=TIERS, default="rf",
                   help="fidelity tier: rf = full time-domain chain, link = closed-form budget")
    p.add_argument("--at-s", type=float, default=None, metavar="T",
                   help="survey missions: evaluate the shot nearest to T seconds of the mission "
                        "clock (default: the first shot whose beam hits the terrain)")
    p.add_argument("--beam", type=int, default=None, metavar="K",
                   help="survey missions: evaluate beam K of the shot (default 0)")


def _negative_values(p: argparse.ArgumentParser) -> None:
    """Let "-224000,-2504000,..." (a --bounds in Greenland, XMIN negative) be a value, not an
    option: the matcher Python >= 3.13 uses; 3.11's accepts a lone negative number only."""
    p._negative_number_matcher = re.compile(r"-\.?\d")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="chirplidar",
        description="Simulator for FM-chirped lidar with self-chirped homodyne detection.",
        epilog=JSON_NOTE)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("shot", help="simulate one shot and print the Table 4.10 outputs (a "
                       "survey mission: one shot of the survey at its own geometry)",
                       epilog=JSON_NOTE)
    _add_common(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (Table 4.10 names, flags, tier, f_beat_hz; on a "
                        "survey mission also the shot's geometry: t_s, beam, range_m, x_m, y_m, "
                        "surface, incidence_deg, ... and mission_geometry = true)")
    p.add_argument("--plot", metavar="PNG", help="draw the beat spectrum (thesis Fig. 5.2)")
    p.add_argument("--plot-unit", choices=("dBm", "dBm/Hz"), default="dBm",
                   help="spectrum y axis: dBm in one RBW (spectrum analyzer, default) or dBm/Hz")
    p.set_defaults(func=cmd_shot, subparser=p)

    p = sub.add_parser("sweep", help="vary one key and tabulate or plot the outputs (a survey "
                       "mission: the survey shot re-planned at every value)", epilog=JSON_NOTE)
    _add_common(p)
    p.add_argument("--vary", required=True, metavar="KEY",
                   help="key to vary, e.g. atm.Pattn or channel.extra_attenuation_db")
    p.add_argument("--start", type=float, required=True, help="first value")
    p.add_argument("--stop", type=float, required=True, help="last value")
    p.add_argument("--n", type=int, required=True, help="number of values")
    p.add_argument("--repeat", type=int, default=1, help="shots per value (default 1)")
    p.add_argument("--scale", choices=("lin", "log"), default="lin", help="value spacing")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list, one object per value and repeat: x, repeat, the "
                        "Table 4.10 outputs, f_beat_hz and flags (survey missions: and the "
                        "evaluated shot's geometry, as shot --json)")
    p.add_argument("--plot", metavar="PNG", help="draw --y against --x")
    p.add_argument("--x", default="Psig", metavar="NAME",
                   help="plot x: an output name (thesis outputs.NAME ok), 'x' for the varied "
                        "key, or on a survey mission a geometry name such as range_m "
                        "(default Psig)")
    p.add_argument("--y", default="SNR", metavar="NAME",
                   help="plot y: an output name, outputs.CNR = SNR (default SNR)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_sweep, subparser=p)

    p = sub.add_parser("run", help="fly a survey mission over its scene and write a CF NetCDF "
                       "trajectory file")
    p.add_argument("mission", metavar="MISSION", help="survey mission, e.g. "
                   "missions/greenland_uav.toml")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key (e.g. platform.uav.altitude_m=200, "
                        "survey.stop_s=60, chrp.F2=300e6); repeatable")
    p.add_argument("--tier", choices=("link", "baseband", "rf"), default=None,
                   help="override survey.tier: link = closed-form budget (campaigns), rf = full "
                        "time-domain chain (short stretches)")
    p.add_argument("--out", metavar="PATH.nc", default=None,
                   help="results file (default outputs/<mission name>.nc)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the mission's)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing results file (and discard the chunks of an "
                        "unfinished run, unless --resume)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run the chunks on a local Dask cluster of N worker processes "
                        "(default: serially in this process); same results as a serial run")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the chunks on a running Dask cluster, e.g. tcp://host:8786 (its "
                        "workers must see the mission, scene and output paths)")
    p.add_argument("--resume", action="store_true",
                   help="finish an interrupted run: keep the chunks in <out>.chunks/ and "
                        "compute only the missing ones (refused if the run differs)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--dry-run", action="store_true",
                   help="check everything, print the planner's warnings and the run's size "
                        "(shots, estimated time from a short timed pilot, disk), and stop")
    from .mission.preflight import LARGE_RUN_GB, LARGE_RUN_HOURS

    p.add_argument("--yes", action="store_true",
                   help=f"start a large run (estimated above {LARGE_RUN_HOURS:g} h or "
                        f"{LARGE_RUN_GB:g} GB), which is otherwise refused")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("coverage", help="grid the footprints of results files: coverage, "
                       "gaps, height precision, crossovers; CF grid NetCDF and a map")
    _negative_values(p)
    p.add_argument("results", metavar="RESULT.nc", nargs="+",
                   help="files written by chirplidar run (one projection)")
    p.add_argument("--cell-m", type=float, required=True, metavar="C",
                   help="cell size in the results' projected metres")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--bounds", metavar="XMIN,YMIN,XMAX,YMAX", default=None,
                       help="the region as a box of projected metres")
    where.add_argument("--region", default=None, metavar="survey|scene|FILE.geojson",
                       help="survey: the runs' survey polygon (default where there is one); "
                            "scene: the scene's extent; or a GeoJSON polygon (WGS-84)")
    p.add_argument("--min-detections", type=int, default=1, metavar="K",
                   help="detected shots a cell needs to count as covered (default 1)")
    p.add_argument("--out", metavar="GRID.nc", default=None,
                   help="write the grid (CF-1.8, opens in QGIS and Panoply) with the "
                        "crossovers in its group 'crossovers'")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--png", metavar="MAP.png", default=None,
                   help="plan-view map: hillshade, tracks, --var, region, crossovers, summary")
    p.add_argument("--var", default="detected_shots",
                   help="grid variable the map colours (default detected_shots; e.g. covered, "
                        "gap, height_precision_measured, median_snr_db)")
    p.add_argument("--json", action="store_true",
                   help="print the summary as one JSON object (cells_in_region, cells_covered, "
                        "fraction_covered, largest_gap_m, ... region, files)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_coverage)

    p = sub.add_parser("view", help="3-D view of a run (terrain, track and footprints), or a "
                       "plan-view map with --plan")
    _negative_values(p)
    p.add_argument("result", metavar="RESULT.nc", help="a file written by chirplidar run")
    p.add_argument("--var", default="range_error",
                   help="per-shot variable that colours the footprints (default range_error)")
    p.add_argument("--png", metavar="OUT.png", default=None,
                   help="write a PNG off-screen instead of opening a window")
    p.add_argument("--plan", action="store_true",
                   help="plan-view map (hillshade, footprint tracks, footprints coloured by "
                        "--var, survey polygon, scale bar, true-north arrow) instead of 3-D; "
                        "needs --png")
    p.add_argument("--bounds", metavar="XMIN,YMIN,XMAX,YMAX", default=None,
                   help="frame the view to this box of the results' projected metres (e.g. "
                        "--bounds -223500,-2503500,-222500,-2502800); 3-D: crops terrain and "
                        "footprints and fits the camera to the box")
    p.add_argument("--camera-azimuth", type=float, default=None, metavar="DEG",
                   help="3-D: camera direction, clockwise from grid north (default 135, grid "
                        "south-east)")
    p.add_argument("--camera-elevation", type=float, default=None, metavar="DEG",
                   help="3-D: camera elevation above the horizon, -90..90 (default 35)")
    p.add_argument("--zoom", type=float, default=None, metavar="F",
                   help="3-D: zoom factor after fitting the view (2: twice as close; default 1)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("plan", help="choose the line spacing (and altitude, speed, ... when "
                       "asked) that meets a coverage requirement at the least flight time; write "
                       "the mission, a GeoJSON and a QGroundControl plan")
    p.add_argument("mission", metavar="MISSION", help="UAV or aircraft mission with a "
                   "survey_polygon_m, e.g. missions/greenland_uav.toml")
    p.add_argument("--cell-m", type=float, required=True, metavar="C",
                   help="coverage cell size [m]")
    p.add_argument("--min-covered", type=float, required=True, metavar="F",
                   help="fraction of the survey polygon's cells that must be covered")
    p.add_argument("--min-detections", type=int, default=1, metavar="K",
                   help="detected shots a cell needs to count as covered (default 1)")
    p.add_argument("--max-height-precision-m", type=float, default=None, metavar="S",
                   help="largest precision of a cell's mean height (one shot's error over "
                        "sqrt(N); median over the covered cells) [m]")
    p.add_argument("--vary", action="append", default=[], metavar="KEY=START:STOP:N",
                   help="also choose this key (altitude, speed, heading, ...): its values as "
                        "study takes them; at most two")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key for every candidate")
    p.add_argument("--out", default="plan", metavar="PLAN_DIR",
                   help="folder for mission.toml, plan.geojson, mission.plan, plan.json "
                        "(default ./plan)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing plan")
    p.add_argument("--workers", type=int, default=None, help="Dask workers per candidate run")
    p.add_argument("--json", action="store_true", help="print the plan report as JSON")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("study", help="run a survey mission over a grid of one or two keys "
                       "(altitude, line spacing, laser power, material, ...) and tabulate "
                       "detection, SNR, power, ranging and coverage per point",
                       epilog=JSON_NOTE)
    p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                   help="survey mission, e.g. missions/greenland_uav.toml")
    p.add_argument("--vary", metavar="KEY=SPEC", action="append", default=[],
                   help="a key to vary (any --set key, thesis names and scene.<key> too): "
                        "KEY=START:STOP:N (N >= 2 values, add :log for geometric spacing) or "
                        "KEY=V1,V2,... (TOML literals, bare words as strings); at most twice")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key at every point; repeatable")
    p.add_argument("--span-s", type=float, default=None, metavar="S",
                   help="run survey.start_s .. start_s + S of each point (default: the whole "
                        "mission)")
    p.add_argument("--cell-m", type=float, default=None, metavar="C",
                   help="also the covered fraction of the survey area on C-metre cells")
    p.add_argument("--tier", choices=("link", "baseband", "rf"), default=None,
                   help="override survey.tier (default: the mission's)")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed of every point (default: the mission's)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON list, one object per point: the varied keys and the "
                        "metrics")
    p.add_argument("--plot", metavar="PNG", default=None,
                   help="draw the metrics against the varied key(s) (checked writable before "
                        "any point runs; written before --out, so a plot that cannot be saved "
                        "leaves no study file)")
    p.add_argument("--out", metavar="STUDY.nc", default=None,
                   help="write the study (one dimension per varied key) to NetCDF")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run each point's chunks on a local Dask cluster of N workers")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run each point's chunks on a running Dask cluster (give --out on "
                        "storage its workers see: the points' temporary files go beside it)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_study, subparser=p)

    p = sub.add_parser("bench", help="time an rf shot against one FFT of the same length")
    p.add_argument("--what", choices=("shot", "effects", "raycast", "scale", "accuracy", "tiers",
                                      "coverage", "campaign"),
                   default="shot",
                   help="shot: an rf shot against one FFT; effects: a shot with each effect on "
                        "and off; raycast: our ray casting against raw embree; tiers: seconds per "
                        "shot of the rf, baseband and link tiers; accuracy: the accuracy-versus-"
                        "time study; scale: the demo mission serially and on 2 Dask workers; "
                        "coverage: chirplidar coverage of generated 10 M and 20 M shot files "
                        "(--shots sets the smaller); campaign: the 91-day satellite campaign "
                        "(missions/icesat2_campaign.toml unless --mission) on --workers")
    p.add_argument("--workers", type=int, default=2,
                   help="campaign: Dask workers (1: serially; default 2)")
    p.add_argument("--triangles", type=int, default=1_000_000,
                   help="raycast: terrain triangles (default 1,000,000)")
    p.add_argument("--rays", type=int, default=200_000, help="raycast: rays per timing")
    p.add_argument("--mission", default=None, metavar="MISSION",
                   help="mission file (default missions/thesis_bench.toml)")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key")
    p.add_argument("--repeats", type=int, default=11,
                   help="timed runs; the median is reported (scale: pairs of runs)")
    p.add_argument("--out", default="outputs", metavar="DIR",
                   help="--what accuracy (the accuracy-versus-time study of every fidelity "
                        "knob, on missions/thesis_ch5_bench.toml unless --mission): folder for "
                        "accuracy_vs_time.{csv,md,png} (default outputs). --what tiers prints "
                        "seconds per shot of the rf, baseband and link tiers")
    p.add_argument("--shots", type=int, default=None,
                   help="accuracy: shots per setting (default 120); coverage: shots of the "
                        "smaller generated file (default 10,000,000)")
    p.add_argument("--json", action="store_true",
                   help='print {"rf_shot_s", "fft_s", "ratio"} (shot), {"none_s", "<effect>_s", '
                        '...} (effects), {"project_rays_per_s", "embree_rays_per_s", "ratio"} '
                        '(raycast), {"rf_shot_s", "baseband_shot_s", "link_shot_s", '
                        '"baseband_speedup", "link_shots_per_s"} (tiers), {"serial_s", '
                        '"workers_2_s", "speedup"} (scale), {"shots", "seconds", "shots_per_s", '
                        '"peak_memory_mb", ...} (coverage), {"days", "passes", "shots", "seconds", '
                '"shots_per_s"} (campaign) or the study rows (accuracy)')
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("passes", help="which satellite passes cross a region in a time "
                       "window: entry, exit, direction, closest approach, beam tracks, sun")
    p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                   help="satellite mission (its TLE or design orbit, beams and attitude; its "
                        "scene is the default region), e.g. missions/icesat_like.toml")
    p.add_argument("--tle", metavar="FILE", default=None,
                   help="instead of MISSION: a TLE file (2 lines, or a name line and 2 lines)")
    p.add_argument("--region", metavar="SCENE.toml|FILE.geojson", default=None,
                   help="the region: a scene's terrain extent, or a GeoJSON Polygon / "
                        "MultiPolygon in WGS-84 lon/lat (default: the mission's scene; "
                        "required with --tle)")
    p.add_argument("--start", required=True, metavar="UTC",
                   help="window start, ISO 8601 with a Z, e.g. 2026-10-05T00:00:00Z")
    p.add_argument("--days", type=float, required=True, metavar="N",
                   help="window length in days (a TLE: within 120 days of its epoch)")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object {"passes": [{"start_utc", "end_utc", '
                        '"direction", "duration_s", "closest_utc", "closest_distance_km", '
                        '"off_nadir_to_centre_deg", "sun_elevation_deg", "beams", '
                        '"nadir_track_lonlat"}, ...], "window", "region", "satellite", '
                        '"tle_epoch_utc"}')
    p.add_argument("--png", metavar="MAP.png", default=None,
                   help="map of the nadir and beam tracks over the region outline")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_passes)

    p = sub.add_parser("demo", help="reproduce thesis Fig. 5.7 (sensitivity of three receivers)")
    p.add_argument("--out", default="outputs", metavar="DIR",
                   help="output folder for fig5_7_sensitivity.{png,csv} (default outputs)")
    p.add_argument("--tier", choices=TIERS, default="rf", help="fidelity tier (default rf)")
    p.add_argument("--points", type=int, default=14, help="points per curve (default 14)")
    p.add_argument("--mission", default=None, metavar="MISSION",
                   help="mission file (default missions/thesis_bench.toml)")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command in ("shot", "sweep", "study"):
            _fix_mission_after_set(args.subparser, args)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)

    from .config import ConfigError

    def show_warning(message, category, filename, lineno, file=None, line=None):
        # Simulator warnings (e.g. detector saturation) as one readable line, no source excerpt.
        print(f"chirplidar {args.command}: warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return int(args.func(args))
    except ConfigError as exc:
        print(f"chirplidar {args.command}: {exc}", file=sys.stderr)
        return 2
    except UsageError as exc:
        print(f"chirplidar {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        hint = ""
        if args.command == "run" and not getattr(args, "dry_run", False):
            from .mission.manifest import chunk_dir_for
            from .mission.runner import default_output

            chunks = chunk_dir_for(Path(args.out) if args.out else default_output(args.mission))
            if chunks.is_dir():
                hint = (f"; the finished chunks are kept in {chunks}: run the same command "
                        "with --resume to finish")
        print(f"chirplidar {args.command}: interrupted{hint}", file=sys.stderr)
        return 130
    except Exception as exc:   # faults in one line; bugs keep their traceback
        fault = _fault_line(args.command, exc)
        if fault is None:
            raise
        if _debug():
            import traceback

            traceback.print_exc()
        print(f"chirplidar {args.command}: {fault[0]}", file=sys.stderr)
        return fault[1]


#: Environment variable: print the traceback of an error that is otherwise shown in one line.
DEBUG_ENV = "CHIRPLIDAR_DEBUG"
#: Exit code of a file-system fault (disk full, permission denied, I/O error): EX_IOERR.
EXIT_IO = 74


def _debug() -> bool:
    return os.environ.get(DEBUG_ENV, "").strip() not in ("", "0")


def _fault_line(command: str, exc: Exception) -> tuple[str, int] | None:
    """(one line, exit code) for an error that is not a bug of the command: a run's fault
    (``runner.RunError``: its own line and code), an OS error of the file system (its file and
    reason, :data:`EXIT_IO`); in ``shot`` and ``sweep`` a ValueError of the physics (a
    configuration it cannot simulate, exit 2); in ``run``, any other error too (what failed,
    exit code 1).
    None: let it raise (traceback)."""
    runner = sys.modules.get("chirplidar.mission.runner")
    if runner is not None and isinstance(exc, getattr(runner, "RunError", ())):
        return str(exc), exc.exit_code
    if isinstance(exc, OSError) and isinstance(exc.errno, int) and exc.errno > 0 \
            and exc.filename is not None:
        return f"{exc.filename}: {os.strerror(exc.errno).lower()}", EXIT_IO
    if command in ("shot", "sweep") and isinstance(exc, ValueError):
        # the physics refuses a configuration it cannot simulate (e.g. a phase screen coarser
        # than r0): the user's input, in one line
        text = (str(exc).strip().splitlines() or [""])[0]
        return f"cannot simulate this configuration: {text}", 2
    if command == "run":
        text = (str(exc).strip().splitlines() or [""])[0]
        what = type(exc).__name__ + (f": {text}" if text else "")
        return f"failed: {what} ({DEBUG_ENV}=1 prints the traceback)", 1
    return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
