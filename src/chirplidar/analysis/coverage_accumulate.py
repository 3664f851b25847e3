"""One pass over the results files of a coverage computation (:mod:`chirplidar.analysis.coverage`):
per-cell counts, sums and SNR histograms, the tracks through each cell, the detection
representatives, the thinned footprint tracks and the flight's time and length, accumulated
block by block (memory grows with the grid, not with the number of shots)."""

from __future__ import annotations

import numpy as np

from .coverage_files import BLOCK_VARIABLES, CoverageError, read_blocks
from .coverage_tracks import TRACK_STEP_PER_CELL, TrackBuilder

EDGE_BAND = 0.01               # footprints closer than C / 100 to a cell edge are "on" it
SNR_RANGE_DB = (-30.0, 90.0)   # per-cell SNR histograms: this range, plus under/overflow bins
SNR_BIN_CHOICES_DB = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)   # the finest whose histograms fit:
SNR_HISTOGRAM_ENTRIES = 1 << 24  # cells x bins at most (64 MB of counts)
GAP_PIXELS_PER_CELL = 20       # detection representatives: pixels of cell_m / 20
FLIGHT_PAUSE_S = 60.0          # a longer step of the shot clock is a pause (between passes)
PLATFORM_STRIDE = 8            # flight length: chords over 8 shots (a turn of radius r at chord
                               # length s reads s^2 / (24 r^2) short: 1e-5 for 1.6 m, r = 100 m)


# ----------------------------------------------------------------------------------- accumulators
class _KeySet:
    """A set of int64 keys, added block by block: each block's keys not yet in the sorted
    set wait in a list, merged into it once they reach a quarter of its size (or 2^20), so
    memory stays near the number of distinct keys however often they recur."""

    def __init__(self):
        self._keys = np.zeros(0, np.int64)     # sorted, distinct
        self._new: list[np.ndarray] = []
        self._n_new = 0

    def add(self, keys: np.ndarray) -> None:
        """Add distinct sorted ``keys`` (``np.unique``'s output)."""
        if keys.size == 0:
            return
        if self._keys.size:
            at = np.minimum(np.searchsorted(self._keys, keys), self._keys.size - 1)
            keys = keys[self._keys[at] != keys]
        if keys.size:
            self._new.append(keys)
            self._n_new += keys.size
            if self._n_new > max(1 << 20, self._keys.size // 4):
                self._merge()

    def _merge(self) -> None:
        if self._new:
            self._keys = np.union1d(self._keys, np.concatenate(self._new))
            self._new, self._n_new = [], 0

    def keys(self) -> np.ndarray:
        self._merge()
        return self._keys


class _Representatives:
    """The pixels that hold a detected footprint centre; a pixel's centre represents them (no
    detection is farther than half its diagonal from its pixel's centre)."""

    def __init__(self, x0: float, y0: float, pixel_m: float):
        self.x0, self.y0, self.pixel = x0, y0, pixel_m
        self._pixels = _KeySet()

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        if x.size == 0:
            return
        inv = 1.0 / self.pixel    # pixel indices offset by 2^30: the key stays positive
        fx, fy = np.floor((x - self.x0) * inv), np.floor((y - self.y0) * inv)
        if max(-fx.min(), fx.max(), -fy.min(), fy.max()) >= (1 << 30):
            raise CoverageError(f"--cell-m {self.pixel * GAP_PIXELS_PER_CELL:g}: too small for "
                                "footprints this far from the region (give larger cells)")
        keys = fx.astype(np.int64) + (1 << 30)
        keys <<= 32
        keys |= fy.astype(np.int64) + (1 << 30)
        # consecutive shots share pixels, or alternate between two across a pixel edge: drop
        # repeats of the last two keys before the sort
        keep = np.ones(keys.size, bool)
        np.not_equal(keys[1:], keys[:-1], out=keep[1:])
        keep[2:] &= keys[2:] != keys[:-2]
        self._pixels.add(np.unique(keys[keep]))

    def points(self) -> np.ndarray:
        """(n, 2) centres of the pixels with a detection."""
        keys = self._pixels.keys()
        ix = (keys >> 32) - (1 << 30)
        iy = (keys & 0xFFFFFFFF) - (1 << 30)
        return np.column_stack([self.x0 + (ix + 0.5) * self.pixel,
                                self.y0 + (iy + 0.5) * self.pixel])



def snr_bin_db(n_cells: int) -> float:
    """Width [dB] of the per-cell SNR histogram bins: the finest of SNR_BIN_CHOICES_DB whose
    histograms fit SNR_HISTOGRAM_ENTRIES; CoverageError when none does."""
    span = SNR_RANGE_DB[1] - SNR_RANGE_DB[0]
    for w in SNR_BIN_CHOICES_DB:
        if n_cells * (round(span / w) + 2) <= SNR_HISTOGRAM_ENTRIES:
            return w
    most = SNR_HISTOGRAM_ENTRIES // (round(span / SNR_BIN_CHOICES_DB[-1]) + 2)
    raise CoverageError(f"--cell-m: {n_cells} cells over the region, more than the {most} the "
                        "per-cell SNR histograms hold; choose larger cells or a smaller region")



def accumulate(files, x0, y0, cell_m, nx, ny, progress) -> dict:
    """One pass over every file's blocks: per-cell counts, sums and SNR histograms, tracks per
    cell, detection representatives (and their k-d tree), thinned tracks, along-track spacings,
    flight time and length."""
    from scipy.spatial import cKDTree

    acc = _Accumulator(x0, y0, cell_m, nx, ny)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(f.n_obs * f.n_beams for f in files), unit="shot", desc="coverage",
                   leave=False)
    try:
        for f in files:
            acc.start_file(f)
            for o0, v in read_blocks(f, BLOCK_VARIABLES):
                acc.add_block(f, o0, v)
                if bar is not None:
                    bar.update(v["x"].size)
    finally:
        if bar is not None:
            bar.close()
    return acc.result(cKDTree)


class _Accumulator:
    """The sums of :func:`accumulate` over the grid of ``nx`` x ``ny`` cells of ``cell_m`` from
    (``x0``, ``y0``), added block by block."""

    def __init__(self, x0, y0, cell_m, nx, ny):
        self.x0, self.y0, self.nx, self.ny = x0, y0, nx, ny
        self.inv_c = 1.0 / cell_m
        self.n_cells = n_cells = nx * ny
        self.shots = np.zeros(n_cells, np.int64)
        self.detected = np.zeros(n_cells, np.int64)
        self.e_n = np.zeros(n_cells, np.int64)
        self.e_sum = np.zeros(n_cells)
        self.e_sq = np.zeros(n_cells)
        self.s_n = np.zeros(n_cells, np.int64)
        self.s_sq = np.zeros(n_cells)
        self.snr_w = snr_bin_db(n_cells)
        self.n_bins = int(round((SNR_RANGE_DB[1] - SNR_RANGE_DB[0]) / self.snr_w)) + 2
        self.snr_hist = np.zeros(n_cells * self.n_bins, np.int32)
        self.cell_tracks = _KeySet()
        self.detected_tracks = _KeySet()     # (cell, track) pairs with a detection: revisits
        self.track_id_of: dict = {}   # (file, track) -> compact id
        self.track_start: dict = {}          # track id -> its first shot's time [s, Unix]
        self.reps = _Representatives(x0, y0, cell_m / GAP_PIXELS_PER_CELL)
        self.tracks = TrackBuilder(cell_m / TRACK_STEP_PER_CELL)
        self.flight_time = self.track_length = 0.0
        self.n_shots = self.n_detected = self.n_in_grid = self.n_on_edge = 0
        self.ext = [np.inf, np.inf, -np.inf, -np.inf]
        self.last_platform = self.last_clock = None

    def start_file(self, f) -> None:
        """A file starts: its clock, platform track and beams' tracks start afresh."""
        self.last_platform = self.last_clock = None
        self.tracks.new_file(f.index, f.n_beams)

    def add_block(self, f, o0: int, v: dict) -> None:
        """Add the block of file ``f`` at obs ``o0`` (variables ``v``, (n_beams, m) arrays)."""
        x, y = v["x"], v["y"]
        nb, m = x.shape
        ok = np.isfinite(x) & np.isfinite(y)
        det = (v["detected"] == 1) & ok
        self._add_counts(x, y, ok, det)
        cell, inside = self._add_cells(x, y)
        d_in = det[inside]
        c_det = cell[d_in]
        self.detected += np.bincount(c_det, minlength=self.n_cells)
        self._add_heights(v, inside, d_in, c_det)
        self._add_snr(v, inside, cell)
        # distinct (file, track) per cell; runs of one cell and track compress first
        tr = v["track"] if "track" in v else np.zeros((nb, m), np.int32)
        tid = _track_ids(tr, f.index, self.track_id_of)
        key = cell * (1 << 24) + tid[inside]
        keep = np.ones(key.size, bool)
        keep[1:] = key[1:] != key[:-1]
        self.cell_tracks.add(np.unique(key[keep]))
        self.detected_tracks.add(np.unique(key[d_in]))
        clock = f.read("delta_time", (0, np.s_[o0:o0 + m]))
        self._add_times(tid, clock, f.epoch_s)
        # detection representatives (every detection, inside the grid or not)
        self.reps.add(x[det], y[det])
        # thinned tracks and along-track spacings
        self.tracks.add(f.index, o0, x, y, tr)
        if "platform_x" in v:
            self._add_track_length(v, clock, m)

    def _add_counts(self, x, y, ok, det) -> None:
        n_ok = int(np.count_nonzero(ok))
        self.n_shots += n_ok
        self.n_detected += int(np.count_nonzero(det))
        if n_ok:
            xo, yo = x[ok], y[ok]
            ext = self.ext
            self.ext = [min(ext[0], float(xo.min())), min(ext[1], float(yo.min())),
                        max(ext[2], float(xo.max())), max(ext[3], float(yo.max()))]

    def _add_cells(self, x, y):
        """(cell index of each shot inside the grid, the inside mask); counts the shots per
        cell and those on a cell edge (NaN positions compare False: outside)."""
        fx = (x - self.x0) * self.inv_c
        fy = (y - self.y0) * self.inv_c
        inside = (fx >= 0) & (fx < self.nx) & (fy >= 0) & (fy < self.ny)
        fxi, fyi = fx[inside], fy[inside]
        ixi, iyi = fxi.astype(np.int64), fyi.astype(np.int64)
        cell = iyi * self.nx + ixi
        self.n_in_grid += cell.size
        rx, ry = fxi - ixi, fyi - iyi
        self.n_on_edge += int(np.count_nonzero(
            (np.minimum(rx, 1.0 - rx) < EDGE_BAND) | (np.minimum(ry, 1.0 - ry) < EDGE_BAND)))
        self.shots += np.bincount(cell, minlength=self.n_cells)
        return cell, inside

    def _add_heights(self, v, inside, d_in, c_det) -> None:
        n_cells = self.n_cells
        if "h_li" in v and "h_li_true" in v:
            err = (v["h_li"][inside] - v["h_li_true"][inside])[d_in]
            good = np.isfinite(err)
            c, e = c_det[good], err[good]
            self.e_n += np.bincount(c, minlength=n_cells)
            self.e_sum += np.bincount(c, weights=e, minlength=n_cells)
            self.e_sq += np.bincount(c, weights=e * e, minlength=n_cells)
        if "h_li_sigma" in v:
            sig = v["h_li_sigma"][inside][d_in]
            good = np.isfinite(sig)
            self.s_n += np.bincount(c_det[good], minlength=n_cells)
            self.s_sq += np.bincount(c_det[good], weights=sig[good] ** 2, minlength=n_cells)

    def _add_snr(self, v, inside, cell) -> None:
        """Into the SNR histograms (NaN snr: no power, the underflow bin)."""
        n_bins = self.n_bins
        if "snr_db" in v:
            b = (v["snr_db"][inside] - SNR_RANGE_DB[0]) * (1.0 / self.snr_w) + 1.0
            b = np.clip(np.nan_to_num(b, nan=0.0), 0.0, n_bins - 1).astype(np.int64)
        else:
            b = np.zeros(cell.size, np.int64)
        key = cell * n_bins + b
        if key.size:
            lo = int(key.min())
            part = np.bincount(key - lo)
            self.snr_hist[lo:lo + part.size] += part.astype(np.int32)

    def _add_times(self, tid, clock, epoch_s: float) -> None:
        """When each track was flown (its first shot; beam 0 carries the shot clock), and the
        flight time: the shot clock's steps, a pause (between a campaign's passes) excluded."""
        m = clock.size
        first = np.ones(m, bool)
        first[1:] = tid[0, 1:] != tid[0, :-1]
        for k, t in zip(tid[0, first].tolist(), (clock[first] + epoch_s).tolist()):
            if t < self.track_start.get(k, np.inf):
                self.track_start[k] = t
        last = self.last_clock
        steps = np.diff(clock if last is None else np.append(last, clock))
        self.flight_time += float(np.sum(steps[steps <= FLIGHT_PAUSE_S]))
        self.last_clock = clock[-1]

    def _add_track_length(self, v, clock, m: int) -> None:
        """Flight length: the platform's ground track (beam 0) through every PLATFORM_STRIDE-th
        shot and the last."""
        at = np.arange(0, m, PLATFORM_STRIDE)
        if (m - 1) % PLATFORM_STRIDE:
            at = np.append(at, m - 1)
        px, py, pt = v["platform_x"][0, at], v["platform_y"][0, at], clock[at]
        if self.last_platform is not None:
            px, py, pt = (np.concatenate([[a], b]) for a, b in
                          zip(self.last_platform, (px, py, pt)))
        chord = np.hypot(np.diff(px), np.diff(py))
        self.track_length += float(np.nansum(chord[np.diff(pt) <= FLIGHT_PAUSE_S]))
        self.last_platform = (px[-1], py[-1], pt[-1])

    def result(self, kd_tree) -> dict:
        """The sums as the dict :func:`accumulate` returns (``kd_tree``: the k-d tree class)."""
        n_cells, n_bins = self.n_cells, self.n_bins
        reps_xy = self.reps.points()
        return {"shots": self.shots, "detected": self.detected, "e_n": self.e_n,
                "e_sum": self.e_sum, "e_sq": self.e_sq, "s_n": self.s_n, "s_sq": self.s_sq,
                "snr_hist": self.snr_hist.reshape(n_cells, n_bins),
                "snr_bin_db": self.snr_w, "cell_tracks": self.cell_tracks.keys(),
                "detected_tracks": self.detected_tracks.keys(),
                "track_start": self.track_start,
                "reps": reps_xy,
                "tree": kd_tree(reps_xy), "tracks": self.tracks.finish(),
                "spacing_hist": self.tracks.spacing_hist,
                "flight_time_s": self.flight_time, "track_length_m": self.track_length,
                "n_shots": self.n_shots, "n_detected": self.n_detected,
                "n_in_grid": self.n_in_grid, "n_on_edge": self.n_on_edge,
                "extent": self.ext, "nx": self.nx, "ny": self.ny}


def _track_ids(track: np.ndarray, file_index: int, ids: dict) -> np.ndarray:
    """Compact ids of the (file, track) pairs of a block (``ids`` grows as pairs appear)."""
    flat = track.ravel()
    starts = np.ones(flat.size, bool)
    starts[1:] = flat[1:] != flat[:-1]
    present = np.unique(flat[starts])                       # tracks come in runs: few
    lut = np.zeros(int(present[-1] - present[0]) + 1, np.int64)
    lut[present - present[0]] = [ids.setdefault((file_index, int(t)), len(ids)) for t in present]
    return lut[track - present[0]]

