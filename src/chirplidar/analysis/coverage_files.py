"""The results files of a coverage computation (:mod:`chirplidar.analysis.coverage`): opened with
h5py, checked for what coverage needs, read block by block along ``obs`` or by windows of one
beam (the crossovers), under the NetCDF lock."""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..mission.results import NETCDF_LOCK

BLOCK_SHOTS = 1 << 20          # shot-beams read per block
WINDOW_CACHE_BYTES = 1 << 28   # crossovers: HDF5 chunks kept decompressed (at least two)

#: The results variables coverage reads (those a file has).
READ_VARIABLES = ("x", "y", "detected", "snr_db", "h_li", "h_li_true", "h_li_sigma",
                  "delta_time", "track", "platform_x", "platform_y")
#: The variables read by blocks (``delta_time``: its ends are read alone).
BLOCK_VARIABLES = tuple(v for v in READ_VARIABLES if v != "delta_time")


class CoverageError(ValueError):
    """Bad input to a coverage computation (one line naming the file, option or key)."""


@dataclass
class ResultsFile:
    """A results file opened for reading (h5py), with what coverage needs from its header."""

    path: Path
    index: int
    h5: object
    epsg: int
    n_beams: int
    n_obs: int
    obs_chunk: int
    has: frozenset
    survey_wkt: str | None
    scene_wkt: str | None
    epoch: _dt.datetime | None    # mission epoch: delta_time = 0

    _cache: dict = field(default_factory=dict)   # HDF5 chunk index -> window variables

    @property
    def epoch_s(self) -> float:
        """The mission epoch as Unix seconds (0 when the file has none): absolute times for
        comparing files."""
        return self.epoch.timestamp() if self.epoch is not None else 0.0

    def read(self, name: str, sl) -> np.ndarray:
        """Variable ``name`` at index ``sl`` (under the NetCDF lock)."""
        with NETCDF_LOCK:
            return self.h5[name][sl]

    def window(self, beam: int, o_lo: int, o_hi: int, names) -> dict:
        """Variables ``names`` of one beam over obs ``o_lo..o_hi`` (clipped to the file), read
        by whole HDF5 chunks kept in a small cache (crossovers revisit the same chunks)."""
        o_lo, o_hi = max(0, o_lo), min(self.n_obs, o_hi)
        c0, c1 = o_lo // self.obs_chunk, (o_hi - 1) // self.obs_chunk
        parts = []
        for c in range(c0, c1 + 1):
            block = self._cache.get(c)
            if block is None:
                sl = (slice(None), slice(c * self.obs_chunk, (c + 1) * self.obs_chunk))
                block = {k: self.read(k, sl) for k in names if k in self.has}
                size = self.obs_chunk * self.n_beams * 8 * len(names)
                if len(self._cache) >= max(2, WINDOW_CACHE_BYTES // size):
                    self._cache.pop(next(iter(self._cache)))   # the oldest
                self._cache[c] = block
            parts.append(block)
        lo = o_lo - c0 * self.obs_chunk
        return {k: np.concatenate([p[k][beam] for p in parts])[lo:lo + o_hi - o_lo]
                for k in parts[0]}

    def close(self) -> None:
        """Close the file."""
        with NETCDF_LOCK:
            self.h5.close()


def _attr_str(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return _attr_str(value.reshape(-1)[0]) if value.size else None
    return str(value)


def _epoch(value) -> _dt.datetime | None:
    text = _attr_str(value)
    try:
        return _dt.datetime.fromisoformat(text.replace("Z", "+00:00")) if text else None
    except ValueError:
        return None


def open_results_file(path, index: int) -> ResultsFile:
    """The results file ``path`` opened for reading (``index``: its place in the list);
    CoverageError when it is missing, unreadable or not a chirplidar results file."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise CoverageError(f"{path}: results file does not exist")
    try:
        with NETCDF_LOCK:
            h5 = h5py.File(path, "r")
    except OSError as exc:
        raise CoverageError(f"{path}: not a readable results file (NetCDF-4/HDF5): {exc}") \
            from None
    try:
        attrs = h5.attrs
        missing = [v for v in ("x", "y", "detected", "delta_time") if v not in h5]
        if missing or _attr_str(attrs.get("featureType")) != "trajectory":
            raise CoverageError(f"{path}: not a chirplidar results file (needs a CF trajectory "
                                f"with x, y, detected, delta_time; missing {missing or 'featureType'})")
        code = _attr_str(attrs.get("epsg_code")) or ""
        if not code.upper().startswith("EPSG:"):
            raise CoverageError(f"{path}: no epsg_code attribute: cannot tell its projection")
        shape = h5["x"].shape
        chunks = h5["x"].chunks
        return ResultsFile(path=path, index=index, h5=h5, epsg=int(code.split(":")[1]),
                            n_beams=int(shape[0]), n_obs=int(shape[1]),
                            obs_chunk=int(chunks[1]) if chunks else max(1, int(shape[1])),
                            has=frozenset(v for v in READ_VARIABLES if v in h5),
                            survey_wkt=_attr_str(attrs.get("survey_polygon_wkt")),
                            scene_wkt=_attr_str(attrs.get("scene_extent_wkt")),
                            epoch=_epoch(attrs.get("mission_epoch")))
    except BaseException:
        with NETCDF_LOCK:
            h5.close()
        raise


def read_blocks(f: ResultsFile, names):
    """(obs start, dict name -> (n_beams, m) array) over the file, HDF5-chunk aligned, for the
    variables ``names`` the file has. The arrays are buffers reused from block to block (fresh
    ones would cost their page faults again: 25 % of the reading): copy what must outlive one."""
    per = max(1, BLOCK_SHOTS // max(f.n_beams, 1))
    step = max(f.obs_chunk, (per // f.obs_chunk) * f.obs_chunk)
    names = [n for n in names if n in f.has]
    with NETCDF_LOCK:
        dsets = {n: f.h5[n] for n in names}
        bufs = {n: np.empty((f.n_beams, min(step, f.n_obs)), dsets[n].dtype) for n in names}
    for o0 in range(0, f.n_obs, step):
        m = min(f.n_obs, o0 + step) - o0
        with NETCDF_LOCK:
            for n in names:
                dsets[n].read_direct(bufs[n], np.s_[:, o0:o0 + m], np.s_[:, :m])
        yield o0, {n: b[:, :m] for n, b in bufs.items()}

