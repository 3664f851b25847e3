"""The lab commands, on the thesis bench or one shot of a survey: ``shot``, ``sweep`` and
``sensitivity`` (thesis Fig. 5.7; ``demo`` is its former name)."""

from __future__ import annotations

import math
import sys
from typing import Sequence

from .common import (JSON_NOTE, SENSITIVITY_TIERS, UsageError, add_common, dump_json, fmt_value,
                     json_number, load_config, overrides_of, resolve_output_name)


def _shot_record(result: dict, names: Sequence[str]) -> dict:
    """The JSON object of one shot: the tier's outputs (Table 4.10 names for the chirped
    tiers), flags, tier and, from the chirped tiers, f_beat_hz."""
    rec = {n: json_number(result[n]) for n in names}
    rec["flags"] = [str(f) for f in result.get("flags", [])]
    rec["tier"] = str(result.get("tier", ""))
    if "f_beat_hz" in result:
        rec["f_beat_hz"] = json_number(result["f_beat_hz"])
    return rec


def _sweep_flags(ds, n_x: int) -> list[list[str]] | None:
    """Per-x flag lists from the sweep's comma-separated ``flags`` variable, if it has one."""
    if "flags" not in ds.data_vars:
        return None
    raw = [str(v) for v in ds["flags"].values.reshape(n_x, -1)[:, 0]]
    return [[f for f in v.split(",") if f] for v in raw]


def cmd_shot(args) -> int:
    from ..api import simulate_mission_shot, simulate_shot
    from ..mission.shot import GEOMETRY_KEYS, is_survey
    from ..tiers.registry import tier_outputs

    if args.plot:
        from ..tiers.registry import TIERS as TIER_REGISTRY

        if not TIER_REGISTRY[args.tier].supports.spectrum:
            drawn = [n for n, t in TIER_REGISTRY.items() if t.supports.spectrum]
            raise UsageError(f"--plot: the {args.tier} tier draws no spectrum; use --tier "
                             f"{' or '.join(drawn)}")
    cfg = load_config(args)
    if is_survey(cfg):
        # A survey mission: one shot of the survey at its own geometry, never the bench channel.
        result = simulate_mission_shot(args.mission, overrides=overrides_of(args), seed=args.seed,
                                       tier=args.tier, at_s=args.at_s,
                                       beam=0 if args.beam is None else args.beam,
                                       return_spectrum=bool(args.plot))
    else:
        result = simulate_shot(cfg, seed=args.seed, tier=args.tier,
                               return_spectrum=bool(args.plot))
    mission_geometry = bool(result.get("mission_geometry"))
    units = tier_outputs(args.tier)[0]
    if args.json:
        rec = _shot_record(result, tuple(units))
        if mission_geometry:
            rec.update({k: json_number(result[k]) for k in GEOMETRY_KEYS})
            rec["mission_geometry"] = True
        print(dump_json(rec))
    else:
        print(f"{args.mission}  tier {result.get('tier', args.tier)}"
              + (f"  seed {args.seed}" if args.seed is not None else ""))
        if mission_geometry:
            r = result
            print(f"  survey shot t = {r['t_s']:.6g} s (shot {r['shot_index']}), beam {r['beam']}: "
                  f"range {r['range_m']:.2f} m to {r['surface']} at x {r['x_m']:.1f} m, "
                  f"y {r['y_m']:.1f} m, incidence {r['incidence_deg']:.1f} deg")
        w = max(9, *(len(name) for name in units))
        for name, unit in units.items():
            print(f"  {name:<{w}} {fmt_value(result[name]):>14}  {unit}")
        if "f_beat_hz" in result:
            f_beat = result["f_beat_hz"]
            print(f"  {'f_beat':<{w}} "
                  f"{fmt_value(f_beat / 1e6 if math.isfinite(f_beat) else f_beat):>14}  MHz")
        flags = result.get("flags", [])
        print(f"  {'flags':<{w}} {', '.join(flags) if flags else '(none)'}")
    if args.plot:
        spectrum = result.get("spectrum")
        if spectrum is None:   # the tiers that declare a spectrum always return one
            raise RuntimeError(f"tier {args.tier!r} returned no spectrum")
        from ..viz.spectrum import plot_beat_spectrum

        where = (f", t = {result['t_s']:.6g} s, beam {result['beam']}, "
                 f"{result['range_m']:.1f} m" if mission_geometry else "")
        path = plot_beat_spectrum(spectrum, args.plot, outputs=result, unit=args.plot_unit,
                                  title=f"Dechirped beat spectrum ({args.mission}{where}, "
                                        f"{result.get('tier', args.tier)} tier)")
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_sweep(args) -> int:
    from ..api import sweep, sweep_mission
    from ..mission.shot import GEOMETRY_KEYS, GEOMETRY_UNITS, is_survey
    from ..tiers.registry import tier_outputs

    if args.n < 1:
        raise UsageError(f"--n must be >= 1, got {args.n}")
    if args.repeat < 1:
        raise UsageError(f"--repeat must be >= 1, got {args.repeat}")
    if args.scale == "log" and (args.start <= 0 or args.stop <= 0):
        raise UsageError(f"--scale log needs positive --start and --stop (got {args.start:g}, "
                         f"{args.stop:g})")
    import numpy as np

    cfg = load_config(args)
    survey = is_survey(cfg)
    # A survey sweep can also plot the evaluated shot's geometry (range_m, incidence_deg, ...).
    geometry_names = [k for k in GEOMETRY_KEYS if k in GEOMETRY_UNITS] if survey else []
    output_units = tier_outputs(args.tier)[0]
    from ..tiers.registry import TIERS as TIER_REGISTRY

    beat = ("f_beat_hz",) if "chirped" in TIER_REGISTRY[args.tier].supports.kinds else ()
    plottable = (*output_units, *beat, *geometry_names)
    x_name = resolve_output_name(args.x, plottable, allow_x=args.vary)
    y_name = resolve_output_name(args.y, plottable, allow_x=args.vary)
    # Check the varied key and both end values before any shot runs (no progress bar for a typo).
    from ..config import ConfigError, config_with

    for value in (args.start, args.stop):
        try:
            config_with(cfg, {args.vary: value})
        except ConfigError as exc:
            msg = str(exc).removeprefix("--set: ").removeprefix("override: ")
            raise ConfigError(f"--vary {args.vary} at {value:g}: {msg}") from None
    if survey:
        # Each point re-plans the mission with the varied key: the shot at that point's geometry.
        ds = sweep_mission(args.mission, args.vary, args.start, args.stop, args.n,
                           overrides=overrides_of(args), repeat=args.repeat, scale=args.scale,
                           seed=args.seed, tier=args.tier, at_s=args.at_s,
                           beam=0 if args.beam is None else args.beam,
                           progress=not args.no_progress)
    else:
        ds = sweep(cfg, args.vary, args.start, args.stop, args.n, repeat=args.repeat,
                   scale=args.scale, seed=args.seed, tier=args.tier,
                   progress=not args.no_progress)
    xs = [float(v) for v in ds["x"].values]
    n_rep = int(ds.sizes.get("repeat", 1))
    names = list(output_units) + (["f_beat_hz"] if "f_beat_hz" in ds.data_vars else [])
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
                rec = {"x": json_number(xv), "repeat": r}
                rec.update({n: json_number(table[n][i, r]) for n in names})
                if flags is not None:
                    rec["flags"] = flags[i]
                if survey:
                    rec.update({k: json_number(v[i]) for k, v in geometry.items()})
                    rec["mission_geometry"] = True
                records.append(rec)
        print(dump_json(records))
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
        units = dict(output_units, f_beat_hz="Hz", **GEOMETRY_UNITS)
        print(f"  {args.vary:>14} {'repeat':>6} "
              + " ".join(f"{c + ' (' + units.get(c, '') + ')':>15}" for c in cols)
              + ("  flags" if flags is not None else ""))
        for i, xv in enumerate(xs):
            for r in range(n_rep):
                print(f"  {xv:>14.6g} {r:>6d} "
                      + " ".join(f"{fmt_value(float(table[c][i, r])):>15}" for c in cols)
                      + (f"  {','.join(flags[i])}" if flags is not None and flags[i] else ""))
    if args.plot:
        from ..viz.sensitivity import plot_sweep

        plot_ds = ds
        for k in {x_name, y_name} & set(geometry_names):  # dims (x,) -> (x, repeat) to plot
            plot_ds = plot_ds.assign({k: (("x", "repeat"), table[k], dict(ds[k].attrs))})
        path = plot_sweep(plot_ds, args.plot, x=x_name, y=y_name, x_scale=args.scale)
        print(f"wrote {path}", file=sys.stderr)
    return 0


def cmd_sensitivity(args) -> int:
    from ..thesis_sensitivity import format_summary, run_sensitivity

    result = run_sensitivity(args.out, tier=args.tier, points=args.points, mission=args.mission,
                             seed=args.seed, progress=not args.no_progress)
    print(format_summary(result))
    return 0


def cmd_demo(args) -> int:
    """The former name of ``sensitivity``, kept as a hidden alias."""
    print("chirplidar demo is now chirplidar sensitivity", file=sys.stderr)
    return cmd_sensitivity(args)


def add_shot_parser(sub) -> None:
    """``chirplidar shot``."""
    p = sub.add_parser("shot", help="simulate one shot and print the Table 4.10 outputs (a "
                       "survey mission: one shot of the survey at its own geometry)",
                       epilog=JSON_NOTE)
    add_common(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (Table 4.10 names, flags, tier, f_beat_hz; on a "
                        "survey mission also the shot's geometry: t_s, beam, range_m, x_m, y_m, "
                        "surface, incidence_deg, ... and mission_geometry = true)")
    p.add_argument("--plot", metavar="PNG", help="draw the beat spectrum (thesis Fig. 5.2)")
    p.add_argument("--plot-unit", choices=("dBm", "dBm/Hz"), default="dBm",
                   help="spectrum y axis: dBm in one RBW (spectrum analyzer, default) or dBm/Hz")
    p.set_defaults(func=cmd_shot, subparser=p)


def add_sweep_parser(sub) -> None:
    """``chirplidar sweep``."""
    p = sub.add_parser("sweep", help="vary one key and tabulate or plot the outputs (a survey "
                       "mission: the survey shot re-planned at every value)", epilog=JSON_NOTE)
    add_common(p)
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


def add_sensitivity_parser(sub) -> None:
    """``chirplidar sensitivity`` and its hidden alias ``demo`` (not listed in the help)."""
    for name, func in (("sensitivity", cmd_sensitivity), ("demo", cmd_demo)):
        listed = {"help": "reproduce thesis Fig. 5.7 (sensitivity of three receivers)"} \
            if name == "sensitivity" else {}
        p = sub.add_parser(name, **listed)
        p.add_argument("--out", default="outputs", metavar="DIR",
                       help="output folder for fig5_7_sensitivity.{png,csv} (default outputs)")
        p.add_argument("--tier", choices=SENSITIVITY_TIERS, default="rf",
                       help="fidelity tier (default rf)")
        p.add_argument("--points", type=int, default=14, help="points per curve (default 14)")
        p.add_argument("--mission", default=None, metavar="MISSION",
                       help="mission file (default missions/thesis_ch5_bench.toml)")
        p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
        p.add_argument("--no-progress", action="store_true", help="no progress on stderr")
        p.set_defaults(func=func)
