"""``chirplidar bench --what scale``: a survey run serially and on a 2-worker local Dask cluster.

Both runs are full :func:`runner.run_mission` calls (wall time from the call to its return:
preparation, cluster start-up and shut-down, chunks, merge and summary), of the same mission
with the same seed, into a temporary directory. They are timed in ``repeats`` adjacent pairs,
and which run goes first alternates from pair to pair, so that neither profits from always
following the other. The speedup is the median of the pairs' ratios: the two runs of a pair are
seconds apart, so the machine's slow drifts (a 2-vCPU VM's speed wanders by +-10 % within
minutes) cancel in each ratio, and the median over many pairs keeps single disturbed runs out.
The terrain cache is filled and the modules are imported by an untimed preparation first
(dask.distributed included: a serial run's first chunk file would import it otherwise), so
that neither run pays a one-off cost the other does not. The two results files of each pair
are compared (they must be identical).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

MISSION_NAME = "greenland_uav.toml"
_DATE = "2026-01-01T00:00:00Z"   # fixed date_created: the two files are comparable


def pair_statistics(serial_s, workers_s) -> dict:
    """Medians of the serial and parallel wall times [s] of paired runs, and the median and
    quartiles of the pairs' ratios ``serial_s / workers_s``."""
    serial_s = np.asarray(serial_s, dtype=float)
    workers_s = np.asarray(workers_s, dtype=float)
    if serial_s.shape != workers_s.shape or serial_s.ndim != 1 or serial_s.size == 0:
        raise ValueError(f"serial_s and workers_s must be two 1-D sequences of one time per pair, "
                         f"got shapes {serial_s.shape} and {workers_s.shape}")
    if not (np.all(np.isfinite(serial_s)) and np.all(np.isfinite(workers_s))
            and np.all(serial_s > 0) and np.all(workers_s > 0)):
        raise ValueError("run times must be finite and > 0 s")
    ratios = serial_s / workers_s
    q25, q75 = np.percentile(ratios, [25, 75])
    return {"serial_s": float(np.median(serial_s)), "workers_s": float(np.median(workers_s)),
            "speedup": float(np.median(ratios)), "speedup_quartiles": [float(q25), float(q75)],
            "pair_speedups": [float(r) for r in ratios]}


def bench_scale(mission=None, overrides=(), *, workers: int = 2, repeats: int = 11,
                progress=None) -> dict:
    """Wall seconds of a serial run and of a run with ``workers`` Dask workers over ``repeats``
    pairs (see the module docstring), the speedup (median of the pairs' ratios, with its
    quartiles and every pair's ratio), the parts of each run (the median pair's
    ``runner.RunResult.timings``) and whether every pair's two files are identical.
    ``progress(line)``, if given, is called after each pair."""
    import xarray as xr

    from ..mission.preflight import prepare
    from ..mission.results import read_netcdf
    from ..mission.runner import run_mission
    from ..mission_files import default_mission_path

    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    mission = Path(mission) if mission is not None else default_mission_path(MISSION_NAME)
    # Untimed: the terrain cache and the imports, dask.array (xarray imports it),
    # dask.distributed (a serial run's first chunk file write asks it for a client) and h5py
    # (the merge's).
    prepare(mission, overrides=list(overrides))
    xr.Variable(("obs",), [0.0])
    import dask.distributed  # noqa: F401
    import h5py  # noqa: F401
    pairs = []
    identical = True
    with tempfile.TemporaryDirectory(prefix="chirplidar-scale-") as tmp:
        tmp = Path(tmp)
        for k in range(repeats):
            runs = {}
            for n in ((None, workers) if k % 2 == 0 else (workers, None)):
                out = tmp / f"{'serial' if n is None else 'workers'}_{k}.nc"
                t0 = time.perf_counter()
                res = run_mission(mission, overrides=list(overrides), out=out,
                                  date_created=_DATE, workers=n)
                runs[n] = (time.perf_counter() - t0, res)
            (serial_s, serial), (par_s, par) = runs[None], runs[workers]
            pairs.append((serial_s, par_s, serial, par))
            try:
                xr.testing.assert_identical(read_netcdf(serial.path), read_netcdf(par.path))
            except AssertionError:
                identical = False
            serial.path.unlink()
            par.path.unlink()
            if progress is not None:
                progress(f"pair {k + 1}/{repeats}: serial {serial_s:.2f} s, {workers} workers "
                         f"{par_s:.2f} s, x{serial_s / par_s:.2f}")
    stats = pair_statistics([p[0] for p in pairs], [p[1] for p in pairs])
    mid = sorted(pairs, key=lambda p: p[0] + p[1])[len(pairs) // 2]
    return {
        "mission": str(mission), "shots": mid[2].summary["shots"], "workers": workers,
        "repeats": repeats, "serial_s": stats["serial_s"],
        f"workers_{workers}_s": stats["workers_s"], "speedup": stats["speedup"],
        "speedup_quartiles": stats["speedup_quartiles"],
        "pair_speedups": stats["pair_speedups"],
        "serial_parts_s": dict(mid[2].timings), "workers_parts_s": dict(mid[3].timings),
        "identical": identical,
    }


def format_scale(res: dict) -> str:
    w = res["workers"]
    parts = res["workers_parts_s"]
    q25, q75 = res["speedup_quartiles"]
    lines = [
        (f"{res['mission']}: {res['shots']} shots, {res['repeats']} pairs of runs: serial "
         f"{res['serial_s']:.2f} s, {w} workers {res[f'workers_{w}_s']:.2f} s (medians); "
         f"speedup {res['speedup']:.2f} (median of the pairs' ratios, quartiles {q25:.2f}-"
         f"{q75:.2f}, range {min(res['pair_speedups']):.2f}-{max(res['pair_speedups']):.2f}; "
         f"goal >= 1.6); results identical: {'yes' if res['identical'] else 'NO'}"),
        "  serial   " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in res["serial_parts_s"].items()),
        f"  {w} workers " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in parts.items()),
    ]
    return "\n".join(lines)


CAMPAIGN_NAME = "icesat2_campaign.toml"


def bench_campaign(mission=None, overrides=(), *, workers: int = 2, progress=None) -> dict:
    """Wall seconds of a whole satellite campaign (default ``missions/icesat2_campaign.toml``,
    91 days) run on ``workers`` local Dask workers (1: serially), from the call to the merged
    file; the terrain cache is filled and the passes found by an untimed preparation first.
    Returns days, passes, shots (records; each has one return per beam), beams, seconds and
    shots_per_s."""
    from ..geometry import earth_orientation as eo
    from ..mission.preflight import prepare
    from ..mission.runner import run_mission
    from ..mission_files import default_mission_path

    path = Path(mission) if mission is not None else default_mission_path(CAMPAIGN_NAME)
    config, _, plan = prepare(path, overrides=list(overrides))
    sv = config.survey
    if sv.start_utc is None:
        raise ValueError(f"{path}: not a campaign (no survey.start_utc / stop_utc)")
    if progress is not None:
        progress(f"campaign {path.name}: {len(plan.pass_starts_s)} passes, {plan.n_shots} shots "
                 f"x {plan.beams.n_beams} beams, {workers} worker(s) ...")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_mission(path, overrides=list(overrides), out=Path(tmp) / "campaign.nc",
                    workers=workers if workers > 1 else None, date_created=_DATE)
        seconds = time.perf_counter() - t0
    return {"days": (eo.mjd_utc(sv.stop_utc) - eo.mjd_utc(sv.start_utc)),
            "passes": int(len(plan.pass_starts_s)), "shots": int(plan.n_shots),
            "beams": int(plan.beams.n_beams), "seconds": seconds,
            "shots_per_s": plan.n_shots / seconds, "workers": int(workers)}


def format_campaign(res: dict) -> str:
    return (f"campaign: {res['days']:.0f} days, {res['passes']} passes, {res['shots']} shots x "
            f"{res['beams']} beams in {res['seconds']:.1f} s on {res['workers']} worker(s): "
            f"{res['shots_per_s']:.3g} shots/s (goal: the 91-day campaign in <= 600 s on 2 cores)")
