"""``chirplidar compare``: one mission flown with several instruments, side by side."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import UsageError, dump_json, json_number, output_path


def cmd_compare(args) -> int:
    from ..analysis.compare import ROWS, compare_instruments, format_table

    if len(args.instrument) < 1:
        raise UsageError("give at least one --instrument FILE (two or more to compare)")
    for path in args.instrument:
        if not Path(path).is_file():
            raise UsageError(f"--instrument {path}: instrument file does not exist")
    if args.span_s is not None and not args.span_s > 0:
        raise UsageError(f"--span-s must be > 0 s, got {args.span_s:g}")
    if not args.cell_m > 0:
        raise UsageError(f"--cell-m must be > 0 m, got {args.cell_m:g}")
    plot = None if args.plot is None else output_path("--plot", args.plot, ".png",
                                                      overwrite=None)
    out_dir = Path(args.out_dir) if args.out_dir else Path("outputs") / "compare"
    results = compare_instruments(args.mission, args.instrument, out_dir=out_dir,
                                  overrides=args.set or [], span_s=args.span_s, seed=args.seed,
                                  cell_m=args.cell_m, progress=not args.no_progress)
    if args.json:
        print(dump_json({"mission": str(args.mission), "cell_m": args.cell_m, "instruments": [
            {"instrument": str(r.instrument), "label": r.label, "results": str(r.results),
             **{key: json_number(r.row.get(key)) for key, _, _ in ROWS},
             "sweep": None if r.sweep is None else {
                 "received_dbm": [json_number(v) for v in r.sweep.received_dbm],
                 "detection_probability": [json_number(v) for v in
                                           r.sweep.detection_probability],
                 "range_precision_m": [json_number(v) for v in r.sweep.range_precision_m]}}
            for r in results]}))
    else:
        print(format_table(results))
        for r in results:
            print(f"{r.label}: results in {r.results}", file=sys.stderr)
    if plot is not None:
        from ..viz.compare import plot_comparison

        plot_comparison(results, plot)
        print(f"wrote {plot}", file=sys.stderr)
    return 0


def add_compare_parser(sub) -> None:
    """``chirplidar compare``."""
    p = sub.add_parser("compare", help="fly one mission with several instruments (chirped or "
                       "pulsed) and tabulate detection, precision, power and bandwidth side by "
                       "side")
    p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                   help="survey mission, e.g. missions/compare_greenland.toml")
    p.add_argument("--instrument", metavar="FILE.toml", action="append", default=[],
                   help="an instrument file to fly (e.g. instruments/glas.toml); repeat it for "
                   "each instrument")
    p.add_argument("--span-s", type=float, default=None, metavar="S",
                   help="fly only the first S seconds of the mission's span")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key for every instrument; repeatable")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the mission's)")
    p.add_argument("--cell-m", type=float, default=50.0, metavar="M",
                   help="coverage cell size (default 50 m)")
    p.add_argument("--out-dir", metavar="DIR", default=None,
                   help="where each instrument's results file goes (default outputs/compare)")
    p.add_argument("--json", action="store_true", help="print the table as one JSON object")
    p.add_argument("--plot", metavar="PNG", default=None,
                   help="save range precision and detection probability against received "
                   "power, one curve per instrument")
    p.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")
    p.set_defaults(func=cmd_compare, subparser=p)
