"""Matplotlib plots of simulation results (PNG files, Agg backend).

Physics modules never import this package; the CLI and the demo import it lazily, only when they
draw. Submodules:

- :mod:`chirplidar.viz.spectrum`: the dechirped beat spectrum of one shot (thesis Fig. 5.2).
- :mod:`chirplidar.viz.sensitivity`: sweep results and SNR-versus-power curves (thesis Fig. 5.7).
- :mod:`chirplidar.viz.planmap`: plan-view maps (coverage grids, tracks, footprints, hillshade),
  built from :mod:`~chirplidar.viz.plan_basemap`, :mod:`~chirplidar.viz.plan_layers` and
  :mod:`~chirplidar.viz.plan_layout`.
- :mod:`chirplidar.viz.study`: mission studies against one or two keys.
- :mod:`chirplidar.viz.scene3d`: the pyvista 3-D track view, built from
  :mod:`~chirplidar.viz.scene3d_geometry` and :mod:`~chirplidar.viz.scene3d_actors`.
- :mod:`chirplidar.viz.conventions`: colours, colour ranges, labels and bounds both views share.
"""

from __future__ import annotations

__all__ = ["plot_beat_spectrum", "plot_sweep", "plot_sensitivity"]


def __getattr__(name: str):
    # Lazy: importing chirplidar.viz does not import matplotlib until a plot function is used.
    if name == "plot_beat_spectrum":
        from .spectrum import plot_beat_spectrum
        return plot_beat_spectrum
    if name in ("plot_sweep", "plot_sensitivity"):
        from . import sensitivity
        return getattr(sensitivity, name)
    raise AttributeError(f"module 'chirplidar.viz' has no attribute {name!r}")
