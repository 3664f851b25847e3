"""The survey commands: ``run`` (and ``run --dry-run``), ``coverage``, ``view`` and ``study``."""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from .common import (JSON_NOTE, SURVEY_TIERS, UsageError, add_instrument_option, tier_help,
                     allow_negative_values, check_cluster_args, dump_json, json_number,
                     output_path, overrides_of)


class LargeRunConsent(argparse.Action):
    """``run --yes``, a flag whose help quotes the preflight limits. The help is read when it is
    shown: :mod:`chirplidar.mission.preflight` imports the geometry stack (trimesh, scipy),
    which every start of the command line would pay for otherwise."""

    def __init__(self, option_strings, dest, default=False, required=False, help=None):
        super().__init__(option_strings, dest, nargs=0, const=True, default=default,
                         required=required)

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, True)

    @property
    def help(self) -> str:
        from ..mission.preflight import LARGE_RUN_GB, LARGE_RUN_HOURS

        return (f"start a large run (estimated above {LARGE_RUN_HOURS:g} h or "
                f"{LARGE_RUN_GB:g} GB), which is otherwise refused")

    @help.setter
    def help(self, value) -> None:
        pass   # argparse.Action.__init__ assigns it; the property above is the help


def cmd_run(args) -> int:
    from ..mission.runner import run_mission
    from ..mission.summary import format_summary

    check_cluster_args(args)
    if args.dry_run:
        return _dry_run(args)
    try:
        result = run_mission(args.mission, overrides=overrides_of(args), tier=args.tier, out=args.out,
                             seed=args.seed, overwrite=args.overwrite,
                             progress=not args.no_progress, workers=args.workers,
                             scheduler=args.scheduler, resume=args.resume, yes=args.yes)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(dump_json({k: json_number(v) for k, v in result.summary.items()}))
    else:
        print(format_summary(result.summary))
    return 0


def _dry_run(args) -> int:
    """``run --dry-run``: the checks, warnings and size of the run; nothing is written."""
    from ..mission import preflight
    from ..mission.runner import check_output, default_output, preflight_run

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
            args.mission, overrides=overrides_of(args), tier=args.tier, seed=args.seed,
            cores=args.workers or 1)
    report = {"mission": str(args.mission), "tier": config.survey.tier,
              "platform": config.platform.kind, "scene": str(scene.path), **estimate.as_dict(),
              "large": estimate.large,
              "planner_warnings": [*planner_warnings, *notes]}
    if args.json:
        print(dump_json({k: json_number(v) for k, v in report.items()}))
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


def cmd_coverage(args) -> int:
    from ..analysis.coverage import (EDGE_WARNING, GRID_VARIABLES, compute_coverage,
                                     summary_json, write_coverage)

    out = png = None
    if args.out is not None:
        out = output_path("--out", args.out, ".nc", overwrite=args.overwrite)
    if args.png is not None:
        png = output_path("--png", args.png, ".png", overwrite=None)   # a picture: replaced
    if args.var not in GRID_VARIABLES:
        raise UsageError(f"--var {args.var}: not a coverage grid variable; choose one of "
                         f"{', '.join(GRID_VARIABLES)}")
    bounds = None
    if args.bounds is not None:
        from ..mission.view import parse_bounds

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

    from ..mission.view import result_terrain
    from ..viz.planmap import plot_plan_map

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
    from ..mission.view import parse_bounds, view_plan, view_result

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


def cmd_study(args) -> int:
    """``chirplidar study``: the survey mission at every point of a grid of one or two keys
    (:mod:`chirplidar.analysis.study`); a table, JSON, a plot and/or a NetCDF study file."""
    from ..analysis.study import check_output_file, run_study
    from ..analysis.study_output import format_study, study_records

    if not args.vary:
        raise UsageError("--vary KEY=START:STOP:N or KEY=V1,V2,... is required")
    check_cluster_args(args)
    if args.plot is not None and not args.plot.lower().endswith(".png"):
        raise UsageError(f"--plot {args.plot}: the plot file must end in .png")
    if args.plot is not None:   # before any point runs (--out: run_study checks it)
        check_output_file("--plot", args.plot, ".png", make_parents=True)
    plot_error: list[OSError] = []

    def plot_first(ds) -> bool:
        # the plot before the study file: a plot that cannot be saved leaves no study file
        from ..viz.study import plot_study

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
        ds = run_study(args.mission, args.vary, overrides=overrides_of(args), span_s=args.span_s,
                       cell_m=args.cell_m, tier=args.tier, seed=args.seed,
                       workers=args.workers, scheduler=args.scheduler,
                       progress=not args.no_progress, out=args.out, overwrite=args.overwrite,
                       before_write=plot_first if args.plot else None)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:   # e.g. the study file on a full disk: one line, no traceback
        raise UsageError(str(exc)) from None
    if args.json:
        print(dump_json([{k: json_number(v) for k, v in rec.items()}
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


def add_run_parser(sub) -> None:
    """``chirplidar run``."""
    p = sub.add_parser("run", help="fly a survey mission over its scene and write a CF NetCDF "
                       "trajectory file")
    p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                   help="survey mission, e.g. missions/greenland_uav.toml")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key (e.g. platform.uav.altitude_m=200, "
                        "survey.stop_s=60, chrp.F2=300e6); repeatable")
    add_instrument_option(p)
    p.add_argument("--tier", choices=SURVEY_TIERS, default=None,
                   help=tier_help("override survey.tier: "))
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
    p.add_argument("--yes", action=LargeRunConsent)
    p.set_defaults(func=cmd_run, subparser=p)


def add_coverage_parser(sub) -> None:
    """``chirplidar coverage``."""
    p = sub.add_parser("coverage", help="grid the footprints of results files: coverage, "
                       "gaps, height precision, crossovers; CF grid NetCDF and a map")
    allow_negative_values(p)
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


def add_view_parser(sub) -> None:
    """``chirplidar view``."""
    p = sub.add_parser("view", help="3-D view of a run (terrain, track and footprints), or a "
                       "plan-view map with --plan")
    allow_negative_values(p)
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


def add_study_parser(sub) -> None:
    """``chirplidar study``."""
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
    add_instrument_option(p)
    p.add_argument("--span-s", type=float, default=None, metavar="S",
                   help="run survey.start_s .. start_s + S of each point (default: the whole "
                        "mission)")
    p.add_argument("--cell-m", type=float, default=None, metavar="C",
                   help="also the covered fraction of the survey area on C-metre cells")
    p.add_argument("--tier", choices=SURVEY_TIERS, default=None,
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
