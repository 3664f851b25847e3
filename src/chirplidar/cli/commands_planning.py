"""The planning commands: ``plan`` (line spacing and flight for a coverage requirement) and
``passes`` (satellite passes over a region)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from .common import UsageError, dump_json, output_path, stderr_lines


def cmd_plan(args) -> int:
    from ..analysis.plan import Requirement, find_plan, format_plan, plan_summary, write_plan

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
    say = stderr_lines(args)
    result = find_plan(args.mission, req, vary=args.vary, overrides=args.set or [],
                       workers=args.workers, progress=say)
    try:
        paths = write_plan(result, out_dir, overwrite=args.overwrite)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(dump_json(plan_summary(result) | {"files": {k: str(v) for k, v in paths.items()}}))
    else:
        print(format_plan(result))
        print(f"  wrote            {', '.join(str(p) for p in paths.values())}")
    return 0 if result.best is not None else 1


#: Longest window of ``chirplidar passes`` (a TLE is refused beyond 120 days of its epoch).
PASSES_MAX_DAYS = 366.0


def cmd_passes(args) -> int:
    from ..analysis.passes import (find_passes, format_passes, orbit_from_mission,
                                   orbit_from_tle_file, passes_report, region_from_geojson,
                                   region_from_scene)
    from ..config import ConfigError
    from ..geometry.earth_orientation import parse_utc, utc_iso

    if (args.mission is None) == (args.tle is None):
        raise UsageError("give a satellite MISSION file or --tle FILE (one of them)")
    png = None if args.png is None else output_path("--png", args.png, ".png", overwrite=None)
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
                             doppler_steering=source.doppler_steering,
                             progress=sys.stderr.isatty() and not args.no_progress)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    report = passes_report(passes, region, source, start, args.days)
    if png is not None:
        from ..viz.passes import plot_passes

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
        print(dump_json(report))
    elif passes:
        print(format_passes(report))
    return 0


def add_plan_parser(sub) -> None:
    """``chirplidar plan``."""
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


def add_passes_parser(sub) -> None:
    """``chirplidar passes``."""
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
