"""Survey missions: scenes (``scene``), planning and geometry (``survey``), per-shot returns
through the tiers (``measure``), the run -- checks before it (``preflight``), one chunk
(``pipeline``), executors (``executors``), chunk directory and resume (``manifest``), summary
(``summary``), faults (``faults``), wired by ``runner`` -- and CF-1.8 trajectory NetCDF results
(the ``results`` package). The runner and scene loader are imported on first use (they pull in
trimesh)."""

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


def __getattr__(name):  # lazy: `import chirplidar.mission` stays light
    if name in ("load_scene", "Scene"):
        from . import scene

        return getattr(scene, name)
    if name in ("run_mission", "RunResult"):
        from . import runner

        return getattr(runner, name)
    raise AttributeError(name)


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
    "load_scene",
    "Scene",
    "run_mission",
    "RunResult",
]
