"""``chirplidar view``: a results file with its scene's terrain, through :mod:`chirplidar.viz.scene3d`."""

from __future__ import annotations

import warnings
from pathlib import Path

from .results import read_netcdf


def result_terrain(ds):
    """The terrain a result was computed on (from its ``scene_file``; cached generated terrain
    loads fast), or None with a warning when the scene file is gone."""
    from .scene import load_scene

    scene_file = ds.attrs.get("scene_file")
    if not scene_file or not Path(scene_file).is_file():
        warnings.warn(f"scene file {scene_file!r} of this result is not available: drawing the "
                      "track without terrain", stacklevel=2)
        return None
    return load_scene(scene_file).terrain


def view_result(path, *, var: str = "range_error", png=None):
    """Draw ``path`` (a ``chirplidar run`` output); returns the PNG path or None (window)."""
    from ..viz.scene3d import render_track, showable_variables

    ds = read_netcdf(path)
    showable = showable_variables(ds)
    if var not in showable:  # before the terrain is loaded
        raise ValueError(f"--var {var}: {path} has no per-shot variable {var!r}; choose one of "
                         f"{', '.join(showable)}")
    return render_track(ds, result_terrain(ds), var=var, png=png)
