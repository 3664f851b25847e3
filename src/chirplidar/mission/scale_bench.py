"""``chirplidar bench --what scale``: a survey run serially and on a 2-worker local Dask cluster.

Both runs are full :func:`runner.run_mission` calls (wall time from the call to its return:
preparation, cluster start-up and shut-down, chunks, merge and summary), of the same mission
with the same seed, into a temporary directory, alternated ``repeats`` times (medians
reported: other load on the machine hits both alike). The terrain cache is filled and the modules are
imported by an untimed preparation first (dask.distributed included: a serial run's first
chunk file would import it otherwise), so that neither run pays a one-off cost the other does
not. The two results files are compared (they must be identical).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

MISSION_NAME = "greenland_uav.toml"
_DATE = "2026-01-01T00:00:00Z"   # fixed date_created: the two files are comparable


def bench_scale(mission=None, overrides=(), *, workers: int = 2, repeats: int = 1) -> dict:
    """Wall seconds of a serial run and of a run with ``workers`` Dask workers (medians of
    ``repeats`` interleaved pairs), their ratio, the parts of each run (the median pair's
    ``runner.RunResult.timings``) and whether the two files are identical."""
    import numpy as np
    import xarray as xr

    from ..bench import default_mission_path
    from .results import read_netcdf
    from .runner import prepare, run_mission

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
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
            t0 = time.perf_counter()
            serial = run_mission(mission, overrides=list(overrides), out=tmp / f"s{k}.nc",
                                 date_created=_DATE)
            t1 = time.perf_counter()
            par = run_mission(mission, overrides=list(overrides), out=tmp / f"w{k}.nc",
                              date_created=_DATE, workers=workers)
            t2 = time.perf_counter()
            pairs.append((t1 - t0, t2 - t1, serial, par))
            try:
                xr.testing.assert_identical(read_netcdf(serial.path), read_netcdf(par.path))
            except AssertionError:
                identical = False
    serial_s = float(np.median([p[0] for p in pairs]))
    par_s = float(np.median([p[1] for p in pairs]))
    mid = sorted(pairs, key=lambda p: p[0] + p[1])[len(pairs) // 2]
    return {
        "mission": str(mission), "shots": mid[2].summary["shots"], "workers": workers,
        "repeats": repeats, "serial_s": serial_s, f"workers_{workers}_s": par_s,
        "speedup": serial_s / par_s, "serial_parts_s": dict(mid[2].timings),
        "workers_parts_s": dict(mid[3].timings), "identical": identical,
    }


def format_scale(res: dict) -> str:
    w = res["workers"]
    parts = res["workers_parts_s"]
    lines = [
        (f"{res['mission']}: {res['shots']} shots, median of {res['repeats']}: serial "
         f"{res['serial_s']:.2f} s, {w} workers {res[f'workers_{w}_s']:.2f} s, speedup "
         f"{res['speedup']:.2f} (goal >= 1.6); results identical: "
         f"{'yes' if res['identical'] else 'NO'}"),
        "  serial   " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in res["serial_parts_s"].items()),
        f"  {w} workers " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in parts.items()),
    ]
    return "\n".join(lines)
