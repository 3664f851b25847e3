"""Mission studies (``chirplidar study``): a survey mission on a grid of one or two mission keys.

What a study answers: how detection, SNR, received power, ranging and (optionally) coverage of a
survey change with the flight altitude, the line spacing, the laser power, the telescope, the
surface material, the threshold, ... before anybody flies it.

Example::

    # the whole demo survey at 4 altitudes x 2 line spacings, with the covered fraction of
    # 50 m cells (8 runs of up to 310 000 shots, ~2 minutes on 2 cores)
    chirplidar study missions/greenland_uav.toml --vary platform.uav.altitude_m=60:480:4:log \\
        --vary platform.uav.line_spacing_m=100,200 --cell-m 50 --plot outputs/altitude.png \\
        --out outputs/altitude_study.nc
    # laser power over the first 20 s of the survey, link tier, as JSON
    chirplidar study missions/greenland_uav.toml --vary lsr.Po=0.002:0.02:5:log --span-s 20 \\
        --tier link --json
    # a flat-scene mission: the surface material (scene key) against the altitude
    chirplidar study my_flat_mission.toml --vary scene.terrain.flat.material=snow,firn,blue_ice \\
        --vary platform.uav.altitude_m=100:1000:10 --span-s 5 --plot outputs/materials.png

    from chirplidar.analysis.study import run_study
    ds = run_study("missions/greenland_uav.toml", ["lsr.Po=0.005:0.05:5:log"], span_s=20.0,
                   tier="link")
    print(ds.median_snr_db.values, ds.detection_probability.values)

The parts of a study, each in its module:

* :mod:`~chirplidar.analysis.study_grid`: the ``--vary`` grammar, the grid's values and the keys'
  units;
* :mod:`~chirplidar.analysis.study_plan`: every point prepared and checked before any runs;
* :mod:`~chirplidar.analysis.study_metrics`: the metrics of a point, read from its results file;
* :mod:`~chirplidar.analysis.study_output`: the study dataset, its NetCDF file, its records
  (``--json``) and table;
* this module: running the points (:func:`run_study`).

Each point is one :func:`~chirplidar.mission.runner.run_mission` into a temporary directory (beside
``out`` when given, else the system's; removed after the point's metrics are read), with
``workers``/``scheduler`` passed through (the same Dask options as ``chirplidar run``; with
``scheduler`` the workers must see the temporary directory: give ``out`` on shared storage).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from .. import _checks
from ..config.loader import ConfigError
from .study_metrics import METRICS, point_metrics
from .study_output import study_dataset, write_study
from .study_plan import plan_study, strip_source


def run_study(mission_path, vary: Sequence, *, overrides=(), span_s: float | None = None,
              cell_m: float | None = None, tier: str | None = None, seed: int | None = None,
              workers: int | None = None, scheduler: str | None = None,
              progress: bool = False, out=None, overwrite: bool = False, cache_dir=None,
              on_point: Callable | None = None,
              budget_bytes: int | None = None,
              before_write: Callable | None = None) -> xr.Dataset:
    """Run the survey mission at every point of the grid of ``vary`` (one or two specs
    ``KEY=START:STOP:N[:log]`` / ``KEY=V1,V2,...`` or
    :class:`~chirplidar.analysis.study_grid.VaryAxis`) and return the study dataset
    (:mod:`~chirplidar.analysis.study_output`); with ``out`` (``.nc``) also write it atomically.

    ``overrides``: the ``--set`` list, applied to every point before its values; ``span_s``:
    run ``survey.start_s .. start_s + span_s`` of each point (else the whole mission); ``tier``
    (``link``, ``baseband``, ``rf``) and ``seed``: as ``chirplidar run`` (the same seed at every
    point); ``workers``/``scheduler``: passed to every point's run; ``progress``: a bar over the
    points. ``on_point(point, path, metrics)`` (a test hook) is called after each point's
    metrics, while its results file still exists. ``before_write(ds)`` is called once every
    point has run, before ``out`` is written (``chirplidar study`` draws its plot there, so that a
    plot that cannot be written leaves no study file behind): when it returns False ``out`` is
    not written, and an exception from it propagates with nothing written. An existing ``out``
    raises FileExistsError before any work unless ``overwrite``; an ``out`` that is a directory,
    or in a directory that is missing or cannot be written, raises ConfigError before any work
    (:func:`check_output_file`). Everything is checked
    (:func:`~chirplidar.analysis.study_plan.plan_study`) before the first point runs.
    """
    from ..mission.executors import check_parallel_args
    from ..mission.runner import run_mission

    try:
        check_parallel_args(workers, scheduler)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    out = _checked_out(out, overwrite)
    plan = plan_study(mission_path, vary, overrides=overrides, span_s=span_s, cell_m=cell_m,
                      tier=tier, seed=seed, cache_dir=cache_dir)
    t0 = time.perf_counter()
    metrics = {name: np.full(plan.shape, np.nan) for name in METRICS}
    metrics["shots"] = np.zeros(plan.shape, dtype=np.int64)
    metrics["detected_shots"] = np.zeros(plan.shape, dtype=np.int64)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(plan.points), unit="point", desc="study", leave=False)
    temp_parent = None if out is None else str(out.parent)
    try:
        for point in plan.points:
            if bar is not None:
                bar.set_postfix_str(point.label(), refresh=False)
            with tempfile.TemporaryDirectory(prefix=".chirplidar-study-",
                                             dir=temp_parent) as tmp:
                path = Path(tmp) / "point.nc"
                try:
                    run_mission(plan.mission_path, overrides=list(point.overrides), tier=tier,
                                out=path, seed=plan.seed, progress=False, cache_dir=cache_dir,
                                workers=workers, scheduler=scheduler)
                except ConfigError as exc:
                    raise ConfigError(f"at {point.label()}: {strip_source(exc)}") from None
                values = point_metrics(path, detection_threshold_db=point.detection_threshold_db,
                                       cell_m=plan.cell_m, budget_bytes=budget_bytes)
                if on_point is not None:
                    on_point(point, path, values)
            for name, value in values.items():
                metrics[name][point.index] = value
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    ds = study_dataset(plan, metrics, elapsed_s=time.perf_counter() - t0)
    write = True
    if before_write is not None:
        write = before_write(ds) is not False
    if out is not None and write:
        write_study(ds, out, overwrite=overwrite)
    return ds


def check_output_file(option: str, path, suffix: str, *, make_parents: bool = False) -> Path:
    """:func:`chirplidar._checks.writable_file`, its error a ConfigError (one line, exit 2)."""
    try:
        return _checks.writable_file(option, path, suffix, make_parents=make_parents)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _checked_out(out, overwrite: bool) -> Path | None:
    """The study file ``out`` as a Path (None for none), checked before any work."""
    if out is None:
        return None
    out = Path(out)
    if out.suffix != ".nc":
        raise ConfigError(f"--out {out}: the study file must end in .nc")
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a directory; name the study file "
                          "(e.g. study.nc)")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists: pass --overwrite to replace it "
                              "(nothing was run)")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    check_output_file("--out", out, ".nc")
    return out
