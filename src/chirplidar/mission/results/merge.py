"""Merge a run's chunk files into its results file, chunk by chunk, as they are finished.

The definitions (dimensions, variables, attributes) are written by netCDF4 from chunk 0; the
``obs`` data of every chunk is then copied with h5py's low-level API, as stored (compressed
HDF5 chunks copied as they are) where the chunk file's layout matches the results file's.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path
from typing import Protocol

import numpy as np

from .files import NETCDF_LOCK, atomic_begin, atomic_commit, write_error
from .schema import COMPRESSION_LEVEL, OBS_DIM, check_obs_chunk, chunk_sizes, is_compressed


class ChunkFiles(Protocol):
    """The chunk files a merge reads (:class:`.writer.ChunkWriter`)."""

    path_dir: Path

    def chunk_path(self, index: int) -> Path: ...

    def is_ready(self, index: int) -> bool: ...

    def chunk_problem(self, index: int) -> str | None: ...


class ChunkMerge:
    """The results file of a chunked run, built while the chunks are being computed.

    Created by :meth:`.writer.ChunkWriter.start_merge` with every chunk's ``obs`` length.
    Each call of :meth:`append_ready` appends the chunks whose files exist, in chunk order,
    from the next missing one on (a parallel run calls it as chunks finish, so the copying
    overlaps the computation of later chunks); :meth:`finish` appends the rest and renames the
    file onto ``path`` atomically. The file is the one
    :meth:`.writer.ChunkWriter.merge_to_file` writes: the temp file ``.<name>.<random>.tmp``
    beside ``path`` until :meth:`finish` (removed by :meth:`abort`, or by leaving the ``with``
    block on an error).

    The definitions (dimensions, variables, attributes) are written by netCDF from chunk 0;
    the ``obs`` data of every chunk is then copied with h5py. Where a chunk file stores a
    variable as the results file does (same HDF5 chunk shape, filters and dtype, aligned on
    the results file's chunk grid: chunks written by :meth:`.writer.ChunkWriter.write` with
    this ``obs_chunk``), its compressed HDF5 chunks are copied as they are; otherwise the
    values are read and written (decompressed and compressed again). A run thus compresses
    each chunk once, in the process that computed it.
    ``on_append(values)`` is called after each chunk with its stored values of the variables
    ``on_append_variables`` (name -> raw array), e.g. for statistics without reading the chunk
    again.
    """

    def __init__(self, writer: ChunkFiles, path, sizes, *, overwrite: bool = False,
                 obs_chunk: int | None = None, on_append=None, on_append_variables=()):
        sizes = [int(m) for m in sizes]
        if not sizes or min(sizes) < 0:
            raise ValueError(f"sizes must be the obs lengths of one or more chunks, got {sizes}")
        self.writer = writer
        self.path = Path(path)
        self.sizes = sizes
        self.overwrite = overwrite
        self.obs_chunk = check_obs_chunk(obs_chunk)
        self.on_append = on_append
        self.on_append_variables = tuple(on_append_variables)
        self.appended = 0              # chunks 0..appended-1 are in the file
        self._tmp = atomic_begin(self.path, overwrite=overwrite)
        self._dst = None               # the temp file (h5py FileID) once chunk 0 is in
        self._targets = {}             # its obs variables: name -> _h5_variable(...)
        self._ref = None               # chunk 0's variables, beams and global attributes
        # name -> {HDF5 chunk offset: digest of its stored bytes}, for the variables whose
        # every chunk was copied as stored (None once one was not): the read-back check
        self._stored: dict[str, dict | None] = {}

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self.abort()
        return False

    @property
    def n_chunks(self) -> int:
        return len(self.sizes)

    @property
    def stored_chunks(self) -> dict[str, dict]:
        """For each variable whose HDF5 chunks were all copied as stored: its chunks' offsets
        and the digests of their bytes (:func:`.read.verify_results_file` reads them back)."""
        return {name: d for name, d in self._stored.items() if d is not None}

    def append_ready(self) -> int:
        """Append the chunks whose files exist, in order, up to the first missing one;
        returns how many were appended."""
        done = self.appended
        while self.appended < self.n_chunks and self.writer.is_ready(self.appended):
            why = self.writer.chunk_problem(self.appended)
            if why is not None:
                raise ValueError(f"chunk {self.appended} ({self.writer.chunk_path(self.appended)})"
                                 f": {why}; not merged (rerun with --resume to recompute it)")
            try:
                with NETCDF_LOCK:
                    self._append(self.appended)
            except Exception as exc:   # a full disk...: an OSError naming the file
                err = write_error(exc, self.path, self._tmp)
                if err is None:
                    raise
                raise err from exc
        return self.appended - done

    def finish(self) -> Path:
        """Append the remaining chunks (ValueError naming the first missing one), close the
        file and rename it onto ``path``; returns ``path``."""
        self.append_ready()
        if self.appended < self.n_chunks:
            missing = [i for i in range(self.appended, self.n_chunks)
                       if not self.writer.is_ready(i)]
            raise ValueError(f"chunks missing in {self.writer.path_dir}: {missing}")
        try:
            self._close_dst()
        except Exception as exc:   # its last data flushed: a full disk...
            err = write_error(exc, self.path, self._tmp)
            if err is None:
                raise
            raise err from exc
        return atomic_commit(self._tmp, self.path, overwrite=self.overwrite)

    def abort(self) -> None:
        """Close and remove the unfinished file (nothing is left at ``path``)."""
        if self._dst is not None:
            # Emptied first: its space is freed, so that closing it (HDF5 writes its metadata)
            # cannot fail on a full disk. (A failed close leaves HDF5 objects that crash the
            # process when they are released later.)
            try:
                os.truncate(self._tmp, 0)
            except OSError:
                pass
        try:
            self._close_dst()
        except Exception:  # noqa: BLE001, S110 - removing it anyway
            pass
        self._dst = None
        self._tmp.unlink(missing_ok=True)

    def _close_dst(self) -> None:
        """Close the temp file (h5py), its variables released first. On a failure (a full disk
        cannot take its last data) the file stays open for :meth:`abort`."""
        self._targets = {}
        if self._dst is not None:
            with NETCDF_LOCK:
                self._dst.close()
            self._dst = None

    def _create(self, ref) -> None:
        """Definitions from chunk 0 (``ref``, open): dimensions with the full obs length,
        variables with their encoding, attributes; variables without ``obs`` copied. netCDF
        then closes the file and h5py opens it for the ``obs`` data."""
        import h5py
        import netCDF4

        with netCDF4.Dataset(self._tmp, "w", format="NETCDF4") as dst:
            for name, dim in ref.dimensions.items():
                dst.createDimension(name, sum(self.sizes) if name == OBS_DIM else len(dim))
            for name, v in ref.variables.items():
                fill = v.getncattr("_FillValue") if "_FillValue" in v.ncattrs() else None
                shape = [len(dst.dimensions[d]) for d in v.dimensions]
                zlib = is_compressed(v.dtype, v.ndim, int(np.prod(shape)))
                # as write_netcdf (xarray passes shuffle=True, used with zlib only)
                chunks = chunk_sizes(v.dimensions, shape, self.obs_chunk) if zlib else None
                out = dst.createVariable(
                    name, v.datatype, v.dimensions, fill_value=fill, zlib=zlib,
                    complevel=COMPRESSION_LEVEL, shuffle=True, chunksizes=chunks)
                out.setncatts({k: v.getncattr(k) for k in v.ncattrs() if k != "_FillValue"})
                out.set_auto_maskandscale(False)
                if OBS_DIM not in v.dimensions:  # beam, crs: the same in every chunk
                    v.set_auto_maskandscale(False)
                    out[...] = v[...]
            dst.setncatts({k: ref.getncattr(k) for k in ref.ncattrs()})
        # h5py's low-level API: its high-level objects cost ~0.1 ms per lookup and property
        self._dst = _h5_open(self._tmp, h5py.h5f.ACC_RDWR)
        self._targets = {name: _h5_variable(self._dst, name) for name, v in
                         ref.variables.items() if OBS_DIM in v.dimensions}
        self._ref = ({k: (v.dtype, v.dimensions) for k, v in ref.variables.items()},
                     ref["beam"][:] if "beam" in ref.variables else None,
                     {k: ref.getncattr(k) for k in ref.ncattrs()})

    def _check(self, i: int, f: Path, src) -> None:
        """Chunk ``i`` against chunk 0: variables, beams, global attributes, obs length."""
        if OBS_DIM not in src.dimensions:
            raise ValueError(f"chunk {i} ({f}): no {OBS_DIM!r} dimension")
        m = len(src.dimensions[OBS_DIM])
        if m != self.sizes[i]:
            raise ValueError(f"chunk {i} ({f}): {m} observations, expected {self.sizes[i]}")
        if i == 0:
            return
        ref_vars, ref_beam, ref_attrs = self._ref
        got = {k: (v.dtype, v.dimensions) for k, v in src.variables.items()}
        if got != ref_vars:
            raise ValueError(f"chunk {i} ({f}): variables differ from chunk 0")
        if ref_beam is not None and not np.array_equal(src["beam"][:], ref_beam):
            raise ValueError(f"chunk {i}: beams differ from chunk 0")
        attrs = {k: src.getncattr(k) for k in src.ncattrs()}
        diff = sorted(k for k in set(attrs) | set(ref_attrs)
                      if k not in attrs or k not in ref_attrs
                      or not np.array_equal(attrs[k], ref_attrs[k]))
        if diff:
            raise ValueError(f"chunk {i} ({f}): global attributes {diff} differ from chunk 0")

    def _append(self, i: int) -> None:
        import h5py
        import netCDF4

        f = self.writer.chunk_path(i)
        start = sum(self.sizes[:i])
        with netCDF4.Dataset(f) as src:
            self._check(i, f, src)
            if i == 0:
                self._create(src)
            axes = {name: v.dimensions.index(OBS_DIM) for name, v in src.variables.items()
                    if OBS_DIM in v.dimensions}
        values = {}
        src = _h5_open(f, h5py.h5f.ACC_RDONLY)
        try:
            for name, axis in axes.items():
                source = _h5_variable(src, name)
                record = self._stored.setdefault(name, {})
                data = _copy_hdf5_variable(source, self._targets[name], axis, start,
                                           last=i == self.n_chunks - 1, record=record)
                if data is not None:
                    self._stored[name] = None
                if name in self.on_append_variables:   # only these: memory stays one variable
                    values[name] = _h5_read(source[0]) if data is None else data
        finally:
            source = None   # released before its file (see _close_dst)
            src.close()
        if self.on_append is not None:
            self.on_append(values)
        self.appended = i + 1


def _h5_open(path, mode):
    """An HDF5 file (h5py low-level ``FileID``) whose close also closes its open objects."""
    import h5py

    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_fclose_degree(h5py.h5f.CLOSE_STRONG)
    return h5py.h5f.open(os.fsencode(path), mode, fapl=fapl)


def _h5_variable(fid, name: str) -> tuple:
    """(dataset id, HDF5 chunk shape or None, filter pipeline, dtype) of variable ``name``."""
    import h5py

    dsid = h5py.h5d.open(fid, name.encode())
    dcpl = dsid.get_create_plist()
    chunks = dcpl.get_chunk() if dcpl.get_layout() == h5py.h5d.CHUNKED else None
    filters = tuple(dcpl.get_filter(k)[:3] for k in range(dcpl.get_nfilters()))
    return dsid, chunks, filters, dsid.dtype


def _h5_read(dsid) -> np.ndarray:
    import h5py

    out = np.empty(dsid.shape, dtype=dsid.dtype)
    dsid.read(h5py.h5s.ALL, h5py.h5s.ALL, out)
    return out


def chunk_digest(data) -> tuple[int, int]:
    """Length and CRC-32 of an HDF5 chunk's stored bytes: a check of a copy (every burst of up
    to 32 bits, and all but 2^-32 of other damage, changes it) at ~4 GB/s, a quarter of a
    cryptographic hash's cost."""
    return len(data), zlib.crc32(data)


def _copy_hdf5_variable(src: tuple, dst: tuple, axis: int, start: int, last: bool,
                        record: dict | None = None):
    """Copy a chunk file's variable ``src`` into the results file's ``dst`` (both from
    :func:`_h5_variable`) at offset ``start`` along ``axis`` (``obs``); ``last``: ``src``
    ends ``dst``.

    When both are chunked alike (chunk shape, filters, dtype) and ``start`` is on ``dst``'s
    chunk grid, the stored (compressed) HDF5 chunks are copied as they are (each one's
    :func:`chunk_digest` put in ``record`` under its offset in ``dst``) and None is
    returned. A chunk reaching past the end of ``src`` (HDF5 stores edge chunks full-size,
    padded) qualifies only when ``src`` is the last: its padding then falls past the end of
    ``dst`` too. Otherwise the values are read, written and returned.
    """
    import h5py

    sid, c = src[0], src[1]
    did = dst[0]
    raw = c is not None and src[1:] == dst[1:] and start % c[axis] == 0
    if raw:
        infos = [sid.get_chunk_info(k) for k in range(sid.get_num_chunks())]
        raw = last or all(o.chunk_offset[axis] + c[axis] <= sid.shape[axis] for o in infos)
    if raw:
        for info in infos:
            mask, chunk = sid.read_direct_chunk(info.chunk_offset)
            offset = list(info.chunk_offset)
            offset[axis] += start
            did.write_direct_chunk(tuple(offset), chunk, mask)
            if record is not None:
                record[tuple(offset)] = chunk_digest(chunk)
        return None
    data = _h5_read(sid)
    index = [slice(None)] * data.ndim
    index[axis] = slice(start, start + data.shape[axis])
    h5py.Dataset(did)[tuple(index)] = data
    return data
