"""``chirplidar bench --what coverage``: shots per second and peak memory of
:func:`~chirplidar.analysis.coverage.compute_coverage` on generated results files.

The files are a UAV lawnmower survey as ``chirplidar run`` writes it (CF trajectory NetCDF in
HDF5 chunks of 1,000,000 compressed shots): lines 20 km long and 200 m apart flown at 20 m/s
and 100 Hz (0.2 m between footprints) over a smooth surface, with the per-shot variables the
coverage reads. Each size is gridded in a fresh process on one core (one BLAS/OpenMP thread),
whose peak resident memory is read back (``ru_maxrss``): two sizes show whether the memory grows
with the file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from shapely.geometry import box

LINE_M = 20_000.0
LINE_SPACING_M = 200.0
SPEED_MPS = 20.0
PRF_HZ = 100.0
CHUNK_SHOTS = 1_000_000
EPSG = 3413
CENTRE_XY_M = (-200_000.0, -2_200_000.0)   # central West Greenland, EPSG:3413
N_LINES = 100
SURVEY_POLYGON = box(CENTRE_XY_M[0] - LINE_M / 2, CENTRE_XY_M[1] - N_LINES * LINE_SPACING_M / 2,
                     CENTRE_XY_M[0] + LINE_M / 2, CENTRE_XY_M[1] + N_LINES * LINE_SPACING_M / 2)


def _chunk(i0: int, n: int, rng: np.random.Generator) -> dict:
    """Per-shot arrays of shots i0 .. i0 + n - 1 of the generated survey (one beam)."""
    i = np.arange(i0, i0 + n)
    per_line = int(LINE_M / SPEED_MPS * PRF_HZ)
    line = i // per_line
    s = (i % per_line) * SPEED_MPS / PRF_HZ
    along = np.where(line % 2 == 0, s, LINE_M - s) - LINE_M / 2
    px = CENTRE_XY_M[0] + along                        # the platform: on the line
    py = CENTRE_XY_M[1] + (line % N_LINES - N_LINES / 2 + 0.5) * LINE_SPACING_M
    x = px + rng.normal(0.0, 0.05, n)                  # footprints: 5 cm pointing jitter
    y = py + rng.normal(0.0, 0.05, n)
    h_true = 800.0 + 0.01 * (x - CENTRE_XY_M[0]) + 20.0 * np.sin((y - CENTRE_XY_M[1]) / 3000.0)
    snr = rng.normal(18.0, 5.0, n)
    detected = np.where(snr >= 10.0, 1, 0).astype(np.int8)
    sigma = 0.046 * 10 ** ((17.6 - snr) / 20.0)
    det = detected == 1
    h = np.where(det, h_true + sigma * rng.standard_normal(n), np.nan)
    return {"delta_time": i / PRF_HZ, "x": x, "y": y, "platform_x": px, "platform_y": py,
            "track": line.astype(np.int32), "h_li_true": h_true, "h_li": h,
            "h_li_sigma": np.where(det, sigma, np.nan), "snr_db": snr,
            "detected": detected}


def synthetic_results(path, shots: int, *, seed: int = 0) -> Path:
    """Write a generated survey results file of ``shots`` shots to ``path`` (streamed chunk by
    chunk: memory bounded by one chunk)."""
    from .. import __version__
    from ..mission.results import ChunkWriter, build_dataset

    path = Path(path)
    n_chunks = -(-int(shots) // CHUNK_SHOTS)
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".coverage_bench.") as tmp:
        writer = ChunkWriter(tmp)
        sizes = []
        for k in range(n_chunks):
            n = min(CHUNK_SHOTS, int(shots) - k * CHUNK_SHOTS)
            per_shot = {name: np.asarray(v)[None, :] for name, v in
                        _chunk(k * CHUNK_SHOTS, n, rng).items()}
            ds = build_dataset(per_shot, epsg=EPSG, epoch_iso="2026-07-01T00:00:00Z",
                               config_toml="generated = true", seed=seed,
                               software_version=__version__,
                               title="chirplidar coverage benchmark survey (generated)",
                               date_created="2026-01-01T00:00:00Z")
            ds.attrs["survey_polygon_wkt"] = SURVEY_POLYGON.wkt
            writer.write(k, ds, obs_chunk=CHUNK_SHOTS)
            sizes.append(n)
        with writer.start_merge(path, sizes, overwrite=True, obs_chunk=CHUNK_SHOTS) as merge:
            return merge.finish()


# Peak resident memory of the child itself: VmHWM (Linux; ru_maxrss would carry over the
# parent's peak across fork and exec), else ru_maxrss.
_PEAK = """
def peak_mb():
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
"""

_CHILD = _PEAK + """
import json, sys, time
t0 = time.perf_counter()
from chirplidar.analysis.coverage import compute_coverage
import xarray
xarray.Dataset({"a": ("x", [1.0])})   # xarray's lazy imports, before the clock starts
t1 = time.perf_counter()
compute_coverage([sys.argv[1]], cell_m=float(sys.argv[2]))
t2 = time.perf_counter()
print(json.dumps({"seconds": t2 - t1, "import_s": t1 - t0, "peak_memory_mb": peak_mb()}))
"""

_IMPORT_ONLY = _PEAK + """
import json
import chirplidar.analysis.coverage, xarray, scipy.spatial, shapely
xarray.Dataset({"a": ("x", [1.0])})
print(json.dumps({"peak_memory_mb": peak_mb()}))
"""


def _child(code: str, *args) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                         text=True, env=env, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"coverage bench child failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_coverage(shots: int = 10_000_000, *, cell_m: float = 100.0, workdir=None,
                   progress=None) -> dict:
    """Grid generated files of ``shots`` and ``2 shots`` shots (the JSON figures are those of
    the first, ``sizes`` has both); returns ``{"shots", "seconds", "shots_per_s",
    "peak_memory_mb", "baseline_memory_mb", "sizes"}``. ``baseline_memory_mb`` is the peak of
    a process that only imports what the coverage uses."""
    if int(shots) < 1:
        raise ValueError(f"shots must be >= 1, got {shots}")
    say = progress or (lambda line: None)
    sizes = []
    with tempfile.TemporaryDirectory(dir=workdir, prefix="chirplidar_coverage_bench.") as tmp:
        for n in (int(shots), 2 * int(shots)):
            path = Path(tmp) / f"survey_{n}.nc"
            t = time.perf_counter()
            say(f"writing a generated results file of {n:,} shots ...")
            synthetic_results(path, n)
            say(f"  written in {time.perf_counter() - t:.0f} s "
                f"({path.stat().st_size / 1e6:.0f} MB); gridding it on one core ...")
            res = _child(_CHILD, path, cell_m)
            sizes.append({"shots": n, "seconds": res["seconds"],
                          "shots_per_s": n / res["seconds"],
                          "peak_memory_mb": res["peak_memory_mb"]})
            say(f"  {res['seconds']:.2f} s, {n / res['seconds']:.3g} shots/s, peak "
                f"{res['peak_memory_mb']:.0f} MB")
            path.unlink()
    base = _child(_IMPORT_ONLY)["peak_memory_mb"]
    return {**sizes[0], "baseline_memory_mb": base, "sizes": sizes}


def format_coverage_bench(res: dict) -> str:
    lines = [f"coverage of generated UAV surveys (cells of 100 m, one core, fresh process each; "
             f"a process that only imports: {res['baseline_memory_mb']:.0f} MB):"]
    for s in res["sizes"]:
        lines.append(f"  {s['shots']:>12,} shots  {s['seconds']:7.2f} s  "
                     f"{s['shots_per_s']:10.3g} shots/s  peak {s['peak_memory_mb']:6.0f} MB")
    lines.append("  goal: >= 2e6 shots/s, peak memory that does not grow with the file")
    return "\n".join(lines)
