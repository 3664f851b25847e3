"""Read results files back: into memory (:func:`read_netcdf`), or every stored value checked
without keeping it (:func:`verify_results_file`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from .files import NETCDF_LOCK
from .schema import OBS_DIM, TRAJECTORY_DIM


def read_netcdf(path) -> xr.Dataset:
    """Read a results file into memory (file closed on return), decoded as written.

    ``time`` stays numeric seconds since the epoch (``xarray.decode_cf(ds)`` for datetimes);
    ``flag_values`` attributes are always 1-D arrays.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist")
    with NETCDF_LOCK, xr.open_dataset(path, engine="netcdf4", decode_times=False,
                                      decode_timedelta=False) as ds:
        ds = ds.load()
    for var in ds.variables.values():
        if "flag_values" in var.attrs:
            var.attrs["flag_values"] = np.atleast_1d(var.attrs["flag_values"])
    return ds


def verify_results_file(path, n_obs: int, n_beams: int, block_obs: int = 1 << 20,
                        stored_chunks=None) -> None:
    """ValueError naming the variable unless every variable of the results file ``path`` has
    ``n_beams`` x ``n_obs`` values along (trajectory, obs) and reads back: decompressed block
    by block, so every stored chunk is checked, or, for the variables in ``stored_chunks``
    (name -> {HDF5 chunk offset: :func:`.merge.chunk_digest`}, from the merge that copied
    them as stored), exactly those chunks with their stored bytes' length and CRC-32 (no
    decompression: they are the bytes of chunk files whose seals were checked)."""
    import netCDF4

    stored_chunks = stored_chunks or {}
    with NETCDF_LOCK:
        try:
            nc = netCDF4.Dataset(path)
        except OSError as exc:
            raise ValueError(f"{path}: cannot be opened ({exc})") from None
        with nc:
            _verify_open(nc, path, n_obs, n_beams, block_obs, set(stored_chunks))
        if stored_chunks:
            _verify_stored(path, stored_chunks)


def _verify_stored(path, stored_chunks) -> None:
    """Each variable of ``stored_chunks`` holds exactly those HDF5 chunks, with the same
    length and CRC-32 (:func:`.merge.chunk_digest`)."""
    import h5py

    from .merge import chunk_digest

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ValueError(f"{path}: cannot be opened ({exc})") from None
    with f:
        for name, expected in stored_chunks.items():
            try:
                dsid = f[name].id
                got = {}
                for k in range(dsid.get_num_chunks()):
                    offset = dsid.get_chunk_info(k).chunk_offset
                    got[tuple(offset)] = chunk_digest(dsid.read_direct_chunk(offset)[1])
            except (KeyError, RuntimeError, OSError) as exc:
                raise ValueError(f"{path}: variable {name} cannot be read ({exc})") from None
            if got != expected:
                bad = sorted(set(got) ^ set(expected)
                             | {k for k in set(got) & set(expected) if got[k] != expected[k]})
                raise ValueError(f"{path}: variable {name}: stored chunks at {bad[:3]} differ "
                                 "from the chunk files copied into it")


def _verify_open(nc, path, n_obs: int, n_beams: int, block_obs: int,
                 by_stored_chunks=frozenset()) -> None:
    """:func:`verify_results_file` on the open dataset ``nc`` (the variables
    ``by_stored_chunks``: their shapes only)."""
    if len(nc.dimensions.get(OBS_DIM, ())) != n_obs:
        raise ValueError(f"{path}: {len(nc.dimensions.get(OBS_DIM, ()))} observations, "
                         f"{n_obs} expected")
    for name, var in nc.variables.items():
        if OBS_DIM not in var.dimensions:
            var[...]
            continue
        axis = var.dimensions.index(OBS_DIM)
        if TRAJECTORY_DIM in var.dimensions and \
                var.shape[var.dimensions.index(TRAJECTORY_DIM)] != n_beams:
            raise ValueError(f"{path}: variable {name} has "
                             f"{var.shape[var.dimensions.index(TRAJECTORY_DIM)]} beams, "
                             f"{n_beams} expected")
        if name in by_stored_chunks:
            continue
        for o0 in range(0, n_obs, block_obs):
            sl = [slice(None)] * var.ndim
            sl[axis] = slice(o0, min(n_obs, o0 + block_obs))
            try:
                var[tuple(sl)]
            except (RuntimeError, OSError) as exc:
                raise ValueError(f"{path}: variable {name} cannot be read at "
                                 f"observations {o0}.. ({exc})") from None
