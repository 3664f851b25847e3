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


#: Serial seconds from which a run counts as a long mission (issue 19: its goal is x1.75).
LONG_MISSION_S = 60.0


def scale_goal(serial_s: float) -> float:
    """The speedup goal on 2 workers: x1.6 for the demo (issue 5), x1.75 for a mission of at
    least :data:`LONG_MISSION_S` serially (issue 19), whose fixed costs matter less."""
    return 1.75 if serial_s >= LONG_MISSION_S else 1.6


def format_scale(res: dict) -> str:
    w = res["workers"]
    parts = res["workers_parts_s"]
    q25, q75 = res["speedup_quartiles"]
    lines = [
        (f"{res['mission']}: {res['shots']} shots, {res['repeats']} pairs of runs: serial "
         f"{res['serial_s']:.2f} s, {w} workers {res[f'workers_{w}_s']:.2f} s (medians); "
         f"speedup {res['speedup']:.2f} (median of the pairs' ratios, quartiles {q25:.2f}-"
         f"{q75:.2f}, range {min(res['pair_speedups']):.2f}-{max(res['pair_speedups']):.2f}; "
         f"goal >= {scale_goal(res['serial_s']):g}); results identical: "
         f"{'yes' if res['identical'] else 'NO'}"),
        "  serial   " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in res["serial_parts_s"].items()),
        f"  {w} workers " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in parts.items()),
    ]
    return "\n".join(lines)


CAMPAIGN_NAME = "icesat2_campaign.toml"
RUN_NAME = "greenland_uav_1h.toml"


class PeakMemory:
    """The peak of the resident memory of this process and all its descendants together (a
    local cluster's workers included), sampled every ``interval_s`` in a thread while the
    ``with`` block runs; ``peak_bytes`` and the peak of each process in ``per_process``."""

    def __init__(self, interval_s: float = 0.2):
        import threading

        self.interval_s = interval_s
        self.peak_bytes = 0
        self.per_process: dict[int, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        import psutil

        me = psutil.Process()
        while True:
            total = 0
            for proc in [me, *me.children(recursive=True)]:
                try:
                    rss = proc.memory_info().rss
                except psutil.Error:   # ended between the listing and the reading
                    continue
                total += rss
                self.per_process[proc.pid] = max(self.per_process.get(proc.pid, 0), rss)
            self.peak_bytes = max(self.peak_bytes, total)
            if self._stop.wait(self.interval_s):
                return

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        return False


def bench_run(mission=None, overrides=(), *, workers: int = 2, progress=None) -> dict:
    """One whole run of a mission (default ``missions/greenland_uav_1h.toml``, the one-hour
    flight) on ``workers`` local Dask workers (1: serially), from the call to the merged,
    verified file; the terrain cache is filled and the modules imported by an untimed
    preparation first. Returns shots, beams, chunks, seconds, shots_per_s, the peak resident
    memory of the run's processes together (``peak_memory_mb``, sampled every 0.2 s; the
    largest single process in ``largest_process_mb``), the file's size, the run's parts and
    what ``run --dry-run`` estimated for it (``estimated_seconds``: its pilot, on as many
    cores as workers)."""
    import warnings

    from ..mission.runner import preflight_run, run_mission
    from ..mission_files import default_mission_path

    path = Path(mission) if mission is not None else default_mission_path(RUN_NAME)
    with warnings.catch_warnings():   # the planner's warnings: the run issues them again
        warnings.simplefilter("ignore")
        _, _, plan, _, estimate = preflight_run(path, overrides=list(overrides), cores=workers)
    import dask.distributed  # noqa: F401  (untimed, as in bench_scale)
    import h5py  # noqa: F401
    if progress is not None:
        progress(f"{path.name}: {plan.n_shots} shots x {plan.beams.n_beams} beam(s) in "
                 f"{plan.n_chunks} chunks on {workers} worker(s) ...")
    with tempfile.TemporaryDirectory(prefix="chirplidar-run-") as tmp:
        out = Path(tmp) / "run.nc"
        with PeakMemory() as memory:
            t0 = time.perf_counter()
            res = run_mission(path, overrides=list(overrides), out=out, date_created=_DATE,
                              workers=workers if workers > 1 else None)
            seconds = time.perf_counter() - t0
        file_mb = out.stat().st_size / 1e6
    return {"mission": str(path), "shots": int(plan.n_shots), "beams": int(plan.beams.n_beams),
            "chunks": int(plan.n_chunks), "workers": int(workers), "seconds": seconds,
            "shots_per_s": plan.n_shots / seconds, "peak_memory_mb": memory.peak_bytes / 1e6,
            "largest_process_mb": max(memory.per_process.values(), default=0) / 1e6,
            "file_mb": file_mb, "estimated_seconds": estimate.seconds,
            "parts_s": dict(res.timings)}


def format_run(res: dict) -> str:
    return (f"{res['mission']}: {res['shots']} shots x {res['beams']} beam(s), "
            f"{res['chunks']} chunks, on {res['workers']} worker(s): {res['seconds']:.1f} s "
            f"({res['shots_per_s']:.3g} shots/s), peak memory {res['peak_memory_mb']:.0f} MB "
            f"(largest process {res['largest_process_mb']:.0f} MB), file "
            f"{res['file_mb']:.0f} MB; --dry-run estimated {res['estimated_seconds']:.0f} s\n  "
            + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in res["parts_s"].items()))


def bench_campaign(mission=None, overrides=(), *, workers: int = 2, progress=None) -> dict:
    """:func:`bench_run` of a whole satellite campaign (default
    ``missions/icesat2_campaign.toml``, 91 days), with its days and passes (the passes found
    by the untimed preparation). Returns days, passes, shots (records; each has one return
    per beam), beams, seconds, shots_per_s and peak_memory_mb."""
    from ..geometry import earth_orientation as eo
    from ..mission.preflight import prepare
    from ..mission_files import default_mission_path

    path = Path(mission) if mission is not None else default_mission_path(CAMPAIGN_NAME)
    config, _, plan = prepare(path, overrides=list(overrides))
    sv = config.survey
    if sv.start_utc is None:
        raise ValueError(f"{path}: not a campaign (no survey.start_utc / stop_utc)")
    if progress is not None:
        progress(f"campaign {path.name}: {len(plan.pass_starts_s)} passes")
    res = bench_run(path, overrides, workers=workers, progress=progress)
    return {"days": (eo.mjd_utc(sv.stop_utc) - eo.mjd_utc(sv.start_utc)),
            "passes": int(len(plan.pass_starts_s)), "shots": res["shots"],
            "beams": res["beams"], "seconds": res["seconds"],
            "shots_per_s": res["shots_per_s"], "workers": int(workers),
            "peak_memory_mb": res["peak_memory_mb"]}


def format_campaign(res: dict) -> str:
    return (f"campaign: {res['days']:.0f} days, {res['passes']} passes, {res['shots']} shots x "
            f"{res['beams']} beams in {res['seconds']:.1f} s on {res['workers']} worker(s): "
            f"{res['shots_per_s']:.3g} shots/s, peak memory {res['peak_memory_mb']:.0f} MB (goal: "
            "the 91-day campaign in <= 600 s on 2 cores)")
