"""``chirplidar bench --what ...``: the timing benchmarks (:mod:`chirplidar.benchmarks`), the
ray casting benchmark and the accuracy-versus-time study."""

from __future__ import annotations

import sys

from .common import UsageError, dump_json, json_number, stderr_lines


def _bench_accuracy_or_tiers(args) -> int:
    """``bench --what tiers`` (seconds per shot of rf, baseband, link) and ``--what accuracy``
    (the accuracy-versus-time study, written to accuracy_vs_time.{csv,md,png} in --out)."""
    if args.what == "tiers":
        from ..benchmarks.timing import bench_tiers

        res = bench_tiers(args.mission, args.set or [], repeats=max(1, min(args.repeats, 5)))
        if args.json:
            print(dump_json(res))
        else:
            print(f"seconds per shot ({args.mission or 'missions/thesis_bench.toml'}), median of "
                  f"{max(1, min(args.repeats, 5))} rounds:")
            print(f"  rf        {res['rf_shot_s'] * 1e3:10.3f} ms   (one shot per call)")
            print(f"  baseband  {res['baseband_shot_s'] * 1e3:10.3f} ms   (256 shots per call; "
                  f"x{res['baseband_speedup']:.1f} faster than rf)")
            print(f"  link      {res['link_shot_s'] * 1e6:10.3f} us   (1,000,000 shots per call; "
                  f"{res['link_shots_per_s']:.3g} shots/s)")
        return 0
    from ..analysis.accuracy import run_accuracy_bench

    if args.shots is not None and args.shots < 2:
        raise UsageError(f"--shots must be >= 2, got {args.shots}")
    kwargs = {} if args.shots is None else {"shots": args.shots}
    say = stderr_lines(args)
    try:
        rows, paths, elapsed = run_accuracy_bench(args.out, args.mission, args.set or [],
                                                  progress=say, **kwargs)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(dump_json({"elapsed_s": elapsed, "files": {k: str(v) for k, v in paths.items()},
                          "rows": [{k: json_number(v) for k, v in r.items()} for r in rows]}))
    else:
        print(paths["md"].read_text())
        for path in paths.values():
            print(f"wrote {path}", file=sys.stderr)
        print(f"study wall time {elapsed:.0f} s", file=sys.stderr)
    return 0


def _bench_startup(args) -> int:
    """``bench --what startup``: ``chirplidar --help`` and ``import chirplidar.units`` in fresh
    processes, median of --repeats."""
    from ..benchmarks.startup import bench_startup, format_startup

    res = bench_startup(repeats=args.repeats)
    if args.json:
        print(dump_json(res))
    else:
        print(format_startup(res))
    return 0


#: ``bench --what survey --json``: the keys of the issue, first (the rest of
#: :func:`..benchmarks.survey.bench_survey`'s result follows them).
SURVEY_KEYS = ("shots", "rays_per_shot", "seconds", "shots_per_s", "embree_rays_per_s",
               "floor_ratio")


def _bench_survey(args) -> int:
    """``bench --what survey``: a link-tier run of the mission (the demo by default) against
    its ray-casting floor on one core, median of min(--repeats, 5) runs."""
    from ..benchmarks.survey import bench_survey, format_survey

    try:
        res = bench_survey(args.mission, args.set or [], repeats=max(1, min(args.repeats, 5)),
                           progress=stderr_lines(args))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        out = {k: json_number(res[k]) for k in SURVEY_KEYS}
        out.update({k: v for k, v in res.items() if k not in SURVEY_KEYS})
        print(dump_json(out))
    else:
        print(format_survey(res))
    return 0


def cmd_bench(args) -> int:
    if args.repeats < 1:
        raise UsageError(f"--repeats must be >= 1, got {args.repeats}")
    if args.what == "startup":
        return _bench_startup(args)
    if args.what in ("accuracy", "tiers"):
        return _bench_accuracy_or_tiers(args)
    if args.what == "survey":
        return _bench_survey(args)
    if args.what == "raycast":
        from ..benchmarks.raycast import bench_raycast

        res = bench_raycast(args.triangles, args.rays, repeats=max(1, min(args.repeats, 5)))
        if args.json:
            print(dump_json({k: res[k] for k in ("project_rays_per_s", "embree_rays_per_s",
                                                 "ratio")}))
        else:
            print(f"ray casting, {res['n_triangles']} triangles, {res['n_rays']} rays "
                  f"(scene build {res['build_s']:.2f} s, not timed):")
            print(f"  chirplidar cast_rays  {res['project_rays_per_s']:.3g} rays/s")
            print(f"  raw embree            {res['embree_rays_per_s']:.3g} rays/s")
            print(f"  ratio                 {res['ratio']:.2f}  (goal >= 0.7)")
        return 0
    if args.what == "scale":
        from ..benchmarks.scale import bench_scale, format_scale

        say = stderr_lines(args)
        res = bench_scale(args.mission, args.set or [], repeats=args.repeats, progress=say)
        if args.json:
            print(dump_json(res))
        else:
            print(format_scale(res))
        return 0
    if args.what in ("run", "campaign") and args.workers < 1:
        raise UsageError(f"--workers must be >= 1 (1: serially), got {args.workers}")
    if args.what == "campaign":
        from ..benchmarks.scale import bench_campaign, format_campaign

        say = stderr_lines(args)
        try:
            res = bench_campaign(args.mission, args.set or [], workers=args.workers,
                                 progress=say)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if args.json:
            print(dump_json({k: json_number(res[k]) for k in ("days", "passes", "shots",
                                                              "seconds", "shots_per_s")}))
        else:
            print(format_campaign(res))
        return 0
    if args.what == "run":
        from ..benchmarks.scale import bench_run, format_run

        say = stderr_lines(args)
        try:
            res = bench_run(args.mission, args.set or [], workers=args.workers, progress=say)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        if args.json:
            print(dump_json({k: (v if isinstance(v, (str, dict)) else json_number(v))
                             for k, v in res.items()}))
        else:
            print(format_run(res))
        return 0
    if args.what == "coverage":
        from ..benchmarks.coverage import bench_coverage, format_coverage_bench

        if args.shots is not None and args.shots < 1000:
            raise UsageError(f"--shots must be >= 1000 for --what coverage, got {args.shots}")
        say = stderr_lines(args)
        res = bench_coverage(10_000_000 if args.shots is None else args.shots, progress=say)
        if args.json:
            print(dump_json({k: (res[k] if k == "sizes" else json_number(res[k]))
                              for k in ("shots", "seconds", "shots_per_s", "peak_memory_mb",
                                        "baseline_memory_mb", "sizes")}))
        else:
            print(format_coverage_bench(res))
        return 0
    from ..benchmarks.timing import bench_effects, bench_shot

    if args.what == "effects":
        res = bench_effects(args.mission, args.set or [], repeats=args.repeats)
        if args.json:
            print(dump_json(res))
        else:
            base = res["none_s"]
            print(f"seconds per rf shot ({args.mission or 'missions/thesis_bench.toml'}), "
                  f"median of {args.repeats}:")
            for key, value in res.items():
                print(f"  {key[:-2]:<12} {value * 1e3:8.2f} ms   x{value / base:.2f}")
        return 0
    res = bench_shot(args.mission, args.set or [], repeats=args.repeats)
    if args.json:
        print(dump_json({k: res[k] for k in ("rf_shot_s", "fft_s", "ratio")}))
    else:
        print(f"rf shot ({args.mission or 'missions/thesis_bench.toml'}): "
              f"{res['rf_shot_s'] * 1e3:.2f} ms")
        print(f"one rfft of N = {res['n_samples']} samples: {res['fft_s'] * 1e3:.3f} ms")
        print(f"ratio shot / FFT: {res['ratio']:.1f}  (median of {args.repeats} shot/FFT pairs, "
              "after warm-up)")
    return 0


def add_bench_parser(sub) -> None:
    """``chirplidar bench``."""
    p = sub.add_parser("bench", help="timing benchmarks (--what): shot, tiers, effects, raycast, "
                       "scale, campaign, run, coverage, survey, startup, and the accuracy-against-"
                       "time "
                       "study")
    p.add_argument("--what", choices=("shot", "effects", "raycast", "scale", "accuracy", "tiers",
                                      "coverage", "campaign", "run", "survey", "startup"),
                   default="shot",
                   help="shot: an rf shot against one FFT; effects: a shot with each effect on "
                        "and off; raycast: our ray casting against raw embree; tiers: seconds per "
                        "shot of the rf, baseband and link tiers; accuracy: the accuracy-versus-"
                        "time study; scale: the demo mission serially and on 2 Dask workers; "
                        "coverage: chirplidar coverage of generated 10 M and 20 M shot files "
                        "(--shots sets the smaller); campaign: the 91-day satellite campaign "
                        "(missions/icesat2_campaign.toml unless --mission) on --workers; "
                        "run: one whole run (missions/greenland_uav_1h.toml, the one-hour "
                        "flight, unless --mission) on --workers, its time and peak memory; "
                        "survey: a link-tier run of the demo (missions/greenland_uav.toml "
                        "unless --mission) on one core against the raw embree call on its own "
                        "rays (floor_ratio; median of min(--repeats, 5) runs); "
                        "startup: chirplidar --help and import chirplidar.units in fresh "
                        "processes")
    p.add_argument("--workers", type=int, default=2,
                   help="campaign, run: Dask workers (1: serially; default 2)")
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
                        "knob, on missions/thesis_ch5_bench.toml unless --mission, and of the "
                        "pulsed tier's on missions/glas_bench.toml): folder for "
                        "accuracy_vs_time.{csv,md,png} (default outputs). --what tiers prints "
                        "seconds per shot of the rf, baseband and link tiers")
    p.add_argument("--shots", type=int, default=None,
                   help="accuracy: shots per setting (default 100; the pulsed study 10 times "
                        "as many); coverage: shots of the "
                        "smaller generated file (default 10,000,000)")
    p.add_argument("--json", action="store_true",
                   help='print {"rf_shot_s", "fft_s", "ratio"} (shot), {"none_s", "<effect>_s", '
                        '...} (effects), {"project_rays_per_s", "embree_rays_per_s", "ratio"} '
                        '(raycast), {"rf_shot_s", "baseband_shot_s", "link_shot_s", '
                        '"baseband_speedup", "link_shots_per_s"} (tiers), {"serial_s", '
                        '"workers_2_s", "speedup", "pair_speedups", "identical", ...} (scale), '
                        '{"shots", "seconds", "shots_per_s", '
                        '"peak_memory_mb", ...} (coverage), {"days", "passes", "shots", "seconds", '
                        '"shots_per_s"} (campaign), {"shots", "seconds", "shots_per_s", '
                        '"peak_memory_mb", ...} (run), {"shots", "rays_per_shot", "seconds", "shots_per_s", '
                        '"embree_rays_per_s", "floor_ratio", ...} (survey), {"help_s", "import_units_s", "python_s", '
                        '"repeats"} (startup) or the study rows (accuracy)')
    p.set_defaults(func=cmd_bench)
