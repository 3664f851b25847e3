"""Write results files: a dataset to one NetCDF file atomically (:func:`write_netcdf`), and a
long run as atomic, sealed chunk files (:class:`ChunkWriter`), merged by :mod:`.merge`."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import xarray as xr

from .files import NETCDF_LOCK, write_atomic, write_bytes_atomic
from .merge import ChunkMerge
from .read import read_netcdf
from .schema import (
    COMPRESSION_LEVEL,
    OBS_DIM,
    SCHEMA_BY_NAME,
    check_dataset,
    check_obs_chunk,
    chunk_sizes,
    is_compressed,
)


def _encoding(ds: xr.Dataset, *, compress: bool = True, obs_chunk: int | None = None,
              obs_unlimited: bool = False) -> dict:
    """xarray's encoding of ``ds``: NaN fill values, compression and HDF5 chunks."""
    enc = {}
    for name, var in ds.variables.items():
        zlib = compress and is_compressed(var.dtype, var.ndim, var.size)
        if np.issubdtype(var.dtype, np.floating):
            spec = SCHEMA_BY_NAME.get(name)
            e = {"_FillValue": None if spec and not spec.nan_allowed else np.nan}
            if zlib:
                e.update(zlib=True, complevel=COMPRESSION_LEVEL)
        elif var.ndim or np.issubdtype(var.dtype, np.integer):
            e = {"_FillValue": None}
        else:
            continue
        # chunked: compressed variables and, along an unlimited obs, all (netCDF's default
        # there is one value per chunk)
        if zlib or (obs_unlimited and OBS_DIM in var.dims):
            chunks = chunk_sizes(var.dims, var.shape, obs_chunk, obs_unlimited=obs_unlimited)
            if chunks is not None:
                e["chunksizes"] = chunks
        enc[name] = e
    return enc


def write_netcdf(ds: xr.Dataset, path, *, overwrite: bool = False,
                 compress: bool = True, obs_chunk: int | None = None) -> Path:
    """Write ``ds`` to ``path`` atomically (temp file in the same directory, fsync, rename).

    An existing ``path`` raises FileExistsError (and is untouched) unless ``overwrite``. On any
    failure no partial file is left at ``path`` and the temp file is removed. Float variables get
    ``_FillValue = NaN`` and zlib compression (``schema.COMPRESSION_LEVEL``; ``compress=False``:
    none, e.g. for temporary chunk files), stored in HDF5 chunks of ``obs_chunk`` observations
    (a run uses its ``survey.chunk_shots``) or, without it, netCDF's default chunking. Returns
    the path.
    """
    return _write_netcdf(ds, path, overwrite=overwrite, compress=compress, obs_chunk=obs_chunk)


def _write_netcdf(ds: xr.Dataset, path, *, overwrite: bool, compress: bool,
                  obs_chunk: int | None, obs_unlimited: bool = False) -> Path:
    """:func:`write_netcdf`; ``obs_unlimited``: ``obs`` is an unlimited dimension, so that
    compressed variables are stored in HDF5 chunks of ``obs_chunk`` observations even when
    there are fewer (see :meth:`ChunkWriter.write`)."""
    if not isinstance(ds, xr.Dataset):
        raise ValueError(f"ds must be an xarray.Dataset, got {type(ds).__name__}")
    obs_chunk = check_obs_chunk(obs_chunk)
    check_dataset(ds)
    encoding = _encoding(ds, compress=compress, obs_chunk=obs_chunk, obs_unlimited=obs_unlimited)
    unlimited = [OBS_DIM] if obs_unlimited and OBS_DIM in ds.dims else None

    def write(tmp):
        with NETCDF_LOCK:
            ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4", encoding=encoding,
                         unlimited_dims=unlimited)

    return write_atomic(path, write, overwrite=overwrite)


# --------------------------------------------------------------------------------------------
# chunk files

_CHUNK_RE = re.compile(r"^chunk_(\d{5})\.nc$")


class ChunkWriter:
    """Write a long run as atomic chunk files ``chunk_00000.nc``, ... in ``path_dir``; merge them.

    A killed run loses no finished chunk: each chunk appears only once fully written.
    ``completed_chunks()`` lists the finished indices (for ``--resume``).

    With a ``run_id`` (a run's identity: its configuration's hash and creation date) every
    chunk gets a seal ``chunk_NNNNN.json`` written after it: its index, the run and the file's
    SHA-256. A chunk counts as finished only with its seal (:meth:`is_ready`);
    :meth:`check_chunks` finds the damaged, truncated, foreign and misplaced ones, and the merge
    checks each chunk's seal before copying it, so none of those is ever merged.
    """

    def __init__(self, path_dir, *, create: bool = True, run_id: str | None = None):
        self.path_dir = Path(path_dir)
        self.run_id = run_id
        if create:
            self.path_dir.mkdir(parents=True, exist_ok=True)

    def seal_path(self, index: int) -> Path:
        return self.chunk_path(index).with_suffix(".json")

    def is_ready(self, index: int) -> bool:
        """The chunk's file exists (and, with a ``run_id``, its seal)."""
        return self.chunk_path(index).is_file() and (
            self.run_id is None or self.seal_path(index).is_file())

    def _seal(self, index: int) -> None:
        import hashlib
        import json

        data = self.chunk_path(index).read_bytes()
        seal = {"index": int(index), "run": self.run_id, "bytes": len(data),
                "sha256": hashlib.sha256(data).hexdigest()}
        write_bytes_atomic(self.seal_path(index), json.dumps(seal).encode("utf-8"))

    def chunk_problem(self, index: int) -> str | None:
        """Why chunk ``index`` cannot be merged (None when its seal vouches for it)."""
        import hashlib
        import json

        path, seal_path = self.chunk_path(index), self.seal_path(index)
        if not path.is_file():
            return "missing"
        if self.run_id is None:
            return None
        try:
            seal = json.loads(seal_path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return "no seal: its write was cut short"
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            return "its seal is unreadable"
        if not isinstance(seal, dict) or seal.get("run") != self.run_id:
            return "from another run"
        if seal.get("index") != index:
            return f"out of place: it is chunk {seal.get('index')}"
        data = path.read_bytes()
        if len(data) != seal.get("bytes"):
            return f"truncated or extended: {len(data)} bytes, {seal.get('bytes')} written"
        if hashlib.sha256(data).hexdigest() != seal.get("sha256"):
            return "damaged: its SHA-256 differs from the one written"
        return None

    def check_chunks(self) -> dict[int, str]:
        """Chunk index -> problem, for every chunk file on disk that cannot be merged."""
        return {i: why for i in self.completed_chunks() if (why := self.chunk_problem(i))}

    def discard(self, index: int) -> None:
        """Remove chunk ``index`` and its seal (to be computed again)."""
        self.chunk_path(index).unlink(missing_ok=True)
        self.seal_path(index).unlink(missing_ok=True)

    def chunk_path(self, index: int) -> Path:
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)) \
                or not 0 <= int(index) <= 99999:
            raise ValueError(f"index must be an integer in 0..99999, got {index!r}")
        return self.path_dir / f"chunk_{int(index):05d}.nc"

    def write(self, index: int, ds: xr.Dataset, *, overwrite: bool = False,
              compress: bool = True, obs_chunk: int | None = None) -> Path:
        """Write chunk ``index`` atomically; an existing chunk raises FileExistsError unless
        ``overwrite``. ``compress=False`` skips zlib (the merged file is compressed anyway).

        ``obs_chunk``: the ``obs_chunk`` of the merged file (a run's chunk length). The chunk's
        compressed variables are then stored in one HDF5 chunk of that shape -- a chunk with
        fewer observations (a run's last) has an unlimited ``obs`` dimension, so that its HDF5
        chunk is still full-size -- and the merge copies them as stored, without decompressing
        and compressing them again (:class:`ChunkMerge`).
        """
        obs_chunk = check_obs_chunk(obs_chunk)
        short = obs_chunk is not None and ds.sizes.get(OBS_DIM, obs_chunk) < obs_chunk
        if self.run_id is not None:
            self.seal_path(index).unlink(missing_ok=True)   # a rewrite is unsealed until done
        path = _write_netcdf(ds, self.chunk_path(index), overwrite=overwrite,
                             compress=compress, obs_chunk=obs_chunk,
                             obs_unlimited=compress and short)
        if self.run_id is not None:
            self._seal(index)
        return path

    def completed_chunks(self) -> list[int]:
        """Sorted indices of the chunks on disk (temp files of a killed write are ignored)."""
        out = []
        for p in self.path_dir.iterdir():
            m = _CHUNK_RE.match(p.name)
            if m and p.is_file():
                out.append(int(m.group(1)))
        return sorted(out)

    def remove_temporaries(self) -> list[Path]:
        """Delete leftover temp files of chunk writes that were killed; returns them."""
        gone = []
        for p in [*self.path_dir.glob(".chunk_*.nc.*.tmp"),
                  *self.path_dir.glob(".chunk_*.json.*.tmp")]:
            p.unlink(missing_ok=True)
            gone.append(p)
        return gone

    def _check_complete(self, n_chunks: int | None) -> int:
        done = self.completed_chunks()
        if not done:
            raise ValueError(f"path_dir: no chunk files in {self.path_dir}")
        n = len(done) if n_chunks is None else int(n_chunks)
        missing = sorted(set(range(n)) - set(done))
        if missing:
            raise ValueError(f"chunks missing in {self.path_dir}: {missing}")
        extra = [i for i in done if i >= n]
        if extra:
            raise ValueError(f"chunks beyond n_chunks={n} in {self.path_dir}: {extra}")
        return n

    def merge_to_file(self, path, *, overwrite: bool = False,
                      n_chunks: int | None = None, obs_chunk: int | None = None) -> Path:
        """Stream chunks 0..n-1 into one file at ``path`` (atomic), chunk by chunk.

        Memory stays bounded by one chunk's variable whatever the number of chunks: the final
        file is created with the full ``obs`` length (the sum of the chunks'), the definitions
        (dimensions, variables, dtypes, compression, fill values, attributes, global attributes)
        copied from chunk 0, and each chunk's stored values are then copied raw (no decoding,
        so NaN fill values and flag dtypes pass unchanged) into their ``obs`` slice. The result
        is the file :func:`write_netcdf` (with the same ``obs_chunk``) would write for the
        concatenated dataset (same values, attributes and encoding: zlib on float
        arrays whether or not the chunks were compressed, and the same HDF5 chunking).

        Chunks must be contiguous from 0 (exactly ``n_chunks`` when given), with the same
        variables, beams and global attributes; ValueError (naming the chunk) otherwise.
        See :meth:`start_merge` to append chunks while later ones are still being computed.
        """
        import netCDF4

        n = self._check_complete(n_chunks)
        sizes = []
        for i in range(n):
            f = self.chunk_path(i)
            with NETCDF_LOCK, netCDF4.Dataset(f) as src:
                if OBS_DIM not in src.dimensions:
                    raise ValueError(f"chunk {i} ({f}): no {OBS_DIM!r} dimension")
                sizes.append(len(src.dimensions[OBS_DIM]))
        with self.start_merge(path, sizes, overwrite=overwrite, obs_chunk=obs_chunk) as merge:
            return merge.finish()

    def start_merge(self, path, sizes, *, overwrite: bool = False,
                    obs_chunk: int | None = None, on_append=None,
                    on_append_variables=()) -> ChunkMerge:
        """A :class:`ChunkMerge` of the chunks of ``obs`` lengths ``sizes`` (chunk 0, 1, ...)
        into ``path``: it appends each chunk, in order, as soon as its file exists."""
        return ChunkMerge(self, path, sizes, overwrite=overwrite, obs_chunk=obs_chunk,
                          on_append=on_append, on_append_variables=on_append_variables)

    def merge(self, path, *, overwrite: bool = False, n_chunks: int | None = None) -> xr.Dataset:
        """Concatenate chunks 0..n-1 along ``obs`` into ``path`` (atomic, streamed by
        :meth:`merge_to_file`) and return the merged dataset read back into memory.

        Chunks must be contiguous from 0 (and exactly ``n_chunks`` when given) with the same
        beams; global attributes come from chunk 0 (and must agree in every chunk).
        """
        return read_netcdf(self.merge_to_file(path, overwrite=overwrite, n_chunks=n_chunks))
