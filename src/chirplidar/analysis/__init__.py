"""Analysis of simulated results: sensitivity, accuracy against time (``accuracy``), coverage
grids and crossovers (``coverage``, its parts in ``coverage_*``), mission studies (``study``, its
parts in ``study_*``); the last three are imported from their modules (they pull in xarray,
shapely and scipy). Nothing here imports matplotlib, pyvista or :mod:`chirplidar.viz` at module
level."""

from .sensitivity import sensitivity_at

__all__ = ["sensitivity_at"]
