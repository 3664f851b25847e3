"""Mission-level outputs: per-shot results as CF-1.8 trajectory NetCDF (see ``results``)."""

from .results import (
    CONVENTIONS,
    DETECTED_FLAG_MEANINGS,
    DETECTED_FLAG_VALUES,
    FEATURE_TYPE,
    OBS_DIM,
    SCHEMA,
    SCHEMA_BY_NAME,
    TRAJECTORY_DIM,
    ChunkWriter,
    VarSpec,
    build_dataset,
    check_dataset,
    read_netcdf,
    write_netcdf,
)

__all__ = [
    "CONVENTIONS",
    "DETECTED_FLAG_MEANINGS",
    "DETECTED_FLAG_VALUES",
    "FEATURE_TYPE",
    "OBS_DIM",
    "SCHEMA",
    "SCHEMA_BY_NAME",
    "TRAJECTORY_DIM",
    "ChunkWriter",
    "VarSpec",
    "build_dataset",
    "check_dataset",
    "read_netcdf",
    "write_netcdf",
]
