"""Command line ``chirplidar``: ``shot``, ``sweep``, ``run``, ``view``, ``bench`` and ``demo``.

Exit codes: 0 success, 1 a run finished but a requested product could not be made (e.g. no
spectrum to plot), 2 bad input (configuration error, unknown name, bad option), 130 interrupted.
Configuration errors are printed to stderr without a traceback.

JSON output has no infinities: a non-finite number is written as ``null``. For the dB outputs
(dBm, dBm/Hz, dB) ``null`` means -inf dB, i.e. zero power (e.g. ``Psig`` with no return).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
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
    from .config import load_mission

    return load_mission(args.mission, args.set or [])


def _fix_mission_after_set(parser: argparse.ArgumentParser, args) -> None:
    """``--set`` takes several KEY=VALUE; a MISSION written after it lands in args.set: move it."""
    if getattr(args, "mission", "") is None:
        if args.set and "=" not in args.set[-1]:
            args.mission = args.set.pop()
        else:
            parser.error("the following arguments are required: MISSION")


# ---------------------------------------------------------------------------------------- commands

def cmd_shot(args) -> int:
    from .api import OUTPUT_NAMES, OUTPUT_UNITS, simulate_shot

    cfg = _load(args)
    result = simulate_shot(cfg, seed=args.seed, tier=args.tier, return_spectrum=bool(args.plot))
    if args.json:
        print(_dump_json(_shot_record(result, OUTPUT_NAMES)))
    else:
        print(f"{args.mission}  tier {result.get('tier', args.tier)}"
              + (f"  seed {args.seed}" if args.seed is not None else ""))
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

        path = plot_beat_spectrum(spectrum, args.plot, outputs=result, unit=args.plot_unit,
                                  title=f"Dechirped beat spectrum ({args.mission}, "
                                        f"{result.get('tier', args.tier)} tier)")
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_sweep(args) -> int:
    from .api import OUTPUT_NAMES, OUTPUT_UNITS, sweep

    if args.n < 1:
        raise UsageError(f"--n must be >= 1, got {args.n}")
    if args.repeat < 1:
        raise UsageError(f"--repeat must be >= 1, got {args.repeat}")
    plottable = (*OUTPUT_NAMES, "f_beat_hz")
    x_name = _resolve_output_name(args.x, plottable, allow_x=args.vary)
    y_name = _resolve_output_name(args.y, plottable, allow_x=args.vary)
    if args.scale == "log" and (args.start <= 0 or args.stop <= 0):
        raise UsageError(f"--scale log needs positive --start and --stop (got {args.start:g}, "
                         f"{args.stop:g})")
    cfg = _load(args)
    # Check the varied key and both end values before any shot runs (no progress bar for a typo).
    from .config import ConfigError, config_with

    for value in (args.start, args.stop):
        try:
            config_with(cfg, {args.vary: value})
        except ConfigError as exc:
            msg = str(exc).removeprefix("--set: ").removeprefix("override: ")
            raise ConfigError(f"--vary {args.vary} at {value:g}: {msg}") from None
    ds = sweep(cfg, args.vary, args.start, args.stop, args.n, repeat=args.repeat,
               scale=args.scale, seed=args.seed, tier=args.tier, progress=not args.no_progress)
    xs = [float(v) for v in ds["x"].values]
    n_rep = int(ds.sizes.get("repeat", 1))
    names = list(OUTPUT_NAMES) + (["f_beat_hz"] if "f_beat_hz" in ds.data_vars else [])
    table = {n: ds[n].transpose("x", ...).values.reshape(len(xs), n_rep) for n in names}
    flags = _sweep_flags(ds, len(xs))
    if args.json:
        records = []
        for i, xv in enumerate(xs):
            for r in range(n_rep):
                rec = {"x": _json_number(xv), "repeat": r}
                rec.update({n: _json_number(table[n][i, r]) for n in names})
                if flags is not None:
                    rec["flags"] = flags[i]
                records.append(rec)
        print(_dump_json(records))
    else:
        cols = [c for c in dict.fromkeys([x_name, y_name, "Psig", "SNR", "d_rx", "d_error"])
                if c != "x"]
        print(f"sweep of {args.vary} ({args.scale}, {args.n} x {n_rep}), tier {args.tier}")
        units = dict(OUTPUT_UNITS, f_beat_hz="Hz")
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

        path = plot_sweep(ds, args.plot, x=x_name, y=y_name, x_scale=args.scale)
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_run(args) -> int:
    from .mission.runner import format_summary, run_mission

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler is not None:
        raise UsageError("--workers and --scheduler are exclusive: --workers N starts a local "
                         "cluster, --scheduler ADDRESS uses a running one")
    if args.scheduler is not None and not args.scheduler.strip():
        raise UsageError("--scheduler needs an address, e.g. tcp://127.0.0.1:8786")
    try:
        result = run_mission(args.mission, overrides=args.set or [], tier=args.tier, out=args.out,
                             seed=args.seed, overwrite=args.overwrite,
                             progress=not args.no_progress, workers=args.workers,
                             scheduler=args.scheduler, resume=args.resume)
    except FileExistsError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(_dump_json({k: _json_number(v) for k, v in result.summary.items()}))
    else:
        print(format_summary(result.summary))
    return 0


def cmd_view(args) -> int:
    from .mission.view import view_result

    try:
        path = view_result(args.result, var=args.var, png=args.png)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if path is not None:
        print(f"wrote {path}", file=sys.stderr)
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="chirplidar",
        description="Simulator for FM-chirped lidar with self-chirped homodyne detection.",
        epilog=JSON_NOTE)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser("shot", help="simulate one shot and print the Table 4.10 outputs",
                       epilog=JSON_NOTE)
    _add_common(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (Table 4.10 names, flags, tier, f_beat_hz)")
    p.add_argument("--plot", metavar="PNG", help="draw the beat spectrum (thesis Fig. 5.2)")
    p.add_argument("--plot-unit", choices=("dBm", "dBm/Hz"), default="dBm",
                   help="spectrum y axis: dBm in one RBW (spectrum analyzer, default) or dBm/Hz")
    p.set_defaults(func=cmd_shot, subparser=p)

    p = sub.add_parser("sweep", help="vary one key and tabulate or plot the outputs",
                       epilog=JSON_NOTE)
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
                        "Table 4.10 outputs, f_beat_hz and flags")
    p.add_argument("--plot", metavar="PNG", help="draw --y against --x")
    p.add_argument("--x", default="Psig", metavar="NAME",
                   help="plot x: an output name (thesis outputs.NAME ok) or 'x' for the varied "
                        "key (default Psig)")
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
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("view", help="3-D view of a run: terrain, track and footprints")
    p.add_argument("result", metavar="RESULT.nc", help="a file written by chirplidar run")
    p.add_argument("--var", default="range_error",
                   help="variable that colours the footprints (default range_error)")
    p.add_argument("--png", metavar="OUT.png", default=None,
                   help="write a PNG off-screen instead of opening a window")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("bench", help="time an rf shot against one FFT of the same length")
    p.add_argument("--what", choices=("shot", "effects", "raycast", "scale", "accuracy", "tiers"),
                   default="shot",
                   help="shot: an rf shot against one FFT; effects: a shot with each effect on "
                        "and off; raycast: our ray casting against raw embree; tiers: seconds per "
                        "shot of the rf, baseband and link tiers; accuracy: the accuracy-versus-"
                        "time study; scale: the demo mission serially and on 2 Dask workers")
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
                   help="accuracy: shots per setting (default 120)")
    p.add_argument("--json", action="store_true",
                   help='print {"rf_shot_s", "fft_s", "ratio"} (shot), {"none_s", "<effect>_s", '
                        '...} (effects), {"project_rays_per_s", "embree_rays_per_s", "ratio"} '
                        '(raycast), {"rf_shot_s", "baseband_shot_s", "link_shot_s", '
                        '"baseband_speedup", "link_shots_per_s"} (tiers), {"serial_s", '
                        '"workers_2_s", "speedup"} (scale) or the study rows (accuracy)')
    p.set_defaults(func=cmd_bench)

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
        if args.command in ("shot", "sweep"):
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
        print("chirplidar: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
