"""Analysis of simulated results: sensitivity, accuracy against time (``accuracy``), coverage
grids and crossovers (``coverage``), mission studies (``study``); the last three are imported
from their modules (they pull in xarray, shapely and scipy)."""

from .sensitivity import sensitivity_at

__all__ = ["sensitivity_at"]
