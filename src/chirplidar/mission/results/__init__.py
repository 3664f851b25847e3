"""Per-shot mission results: a CF-1.8 trajectory dataset in NetCDF-4 files.

One module per job:

- :mod:`.schema`: the variables, their CF attributes and flag meanings, the storage layout
  (compression, HDF5 chunks); the file format is described there.
- :mod:`.dataset`: :func:`build_dataset`, the dataset of per-shot arrays, checked.
- :mod:`.files`: the netCDF lock of this process and atomic file writes.
- :mod:`.writer`: :func:`write_netcdf` (one file) and :class:`ChunkWriter` (a run's sealed
  chunk files).
- :mod:`.merge`: :class:`ChunkMerge`, chunk files into the results file as they are finished.
- :mod:`.read`: :func:`read_netcdf` and :func:`verify_results_file`.

This package's namespace is its interface: the names below are imported from here.
"""

from .dataset import build_dataset
from .files import NETCDF_LOCK, write_atomic, write_bytes_atomic, write_error
from .merge import ChunkMerge
from .read import read_netcdf, verify_results_file
from .schema import (
    BYTES_PER_BEAM_SHOT,
    CONVENTIONS,
    DETECTED_FLAG_MEANINGS,
    DETECTED_FLAG_VALUES,
    FEATURE_TYPE,
    NOT_MEASURED_BY,
    OBS_DIM,
    SCHEMA,
    SCHEMA_BY_NAME,
    TRAJECTORY_DIM,
    VarSpec,
    check_dataset,
    crs_attributes,
)
from .writer import ChunkWriter, write_netcdf

__all__ = [
    "BYTES_PER_BEAM_SHOT",
    "CONVENTIONS",
    "DETECTED_FLAG_MEANINGS",
    "DETECTED_FLAG_VALUES",
    "FEATURE_TYPE",
    "NETCDF_LOCK",
    "NOT_MEASURED_BY",
    "OBS_DIM",
    "SCHEMA",
    "SCHEMA_BY_NAME",
    "TRAJECTORY_DIM",
    "ChunkMerge",
    "ChunkWriter",
    "VarSpec",
    "build_dataset",
    "check_dataset",
    "crs_attributes",
    "read_netcdf",
    "verify_results_file",
    "write_atomic",
    "write_bytes_atomic",
    "write_error",
    "write_netcdf",
]
