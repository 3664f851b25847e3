"""The tracks of a coverage computation (:mod:`chirplidar.analysis.coverage`): footprint
tracks thinned block by block, the along- and across-track spacings, and the crossovers of
tracks refined on the full-rate footprints (see that module's docstring for the definitions)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

TRACK_STEP_PER_CELL = 2        # crossovers and across-track spacing: vertices every C / 2
ACROSS_TRACK_SAMPLES = 20_000  # track vertices the across-track spacing's median is taken over
SPACING_SAMPLE = 16            # the along-track spacing's median: of every 16th footprint pair
MIN_CROSSING_ANGLE_DEG = 5.0   # tracks closer to parallel do not cross (a repeated line)
LINE_TURN_DEG = 30.0           # a beam's footprints follow a line unless more than a fifth
LINE_TURN_FRACTION = 0.2       # of the turns between its vertices exceed 30 degrees
_SPACING_BINS_PER_DECADE = 2000  # along-track spacing median: log bins (0.12 %)
_SPACING_DECADES = (-4.0, 7.0)


@dataclass
class Polyline:
    """A thinned footprint track: vertices (x, y) with their obs indices. Kept as Python lists
    while it grows: thousands of small numpy arrays, long-lived among the blocks' large
    temporaries, fragment the C heap (measured: +70 MB of resident memory over 20 blocks of a
    million shots); Python's own allocator keeps them apart."""

    file: int
    beam: int
    track: int
    x: list = field(default_factory=list)
    y: list = field(default_factory=list)
    obs: list = field(default_factory=list)
    line: bool = True     # False: the footprints do not follow a line (a conical scan): dropped

    def arrays(self):
        return (np.asarray(self.x, float), np.asarray(self.y, float),
                np.asarray(self.obs, np.int64))


class TrackBuilder:
    """Thinned polylines of every (file, beam, track >= 0), built block by block: a vertex every
    ``step_m`` along track, the first and last point of each track, and a break where the
    footprints jump (a beam off the terrain)."""

    def __init__(self, step_m: float):
        self.step = step_m
        self.done: list[Polyline] = []
        # (file, beam) -> [polyline, last x, last y, last obs, along-track distance so far]
        self._open: dict = {}
        lo_dec, hi_dec = _SPACING_DECADES
        #: histogram of the distances between consecutive footprints of a beam (log bins)
        self.spacing_hist = np.zeros(int((hi_dec - lo_dec) * _SPACING_BINS_PER_DECADE) + 2,
                                     np.int64)

    def new_file(self, fi: int, n_beams: int) -> None:
        """A file starts: its beams' tracks start afresh."""
        for b in range(n_beams):
            self._close(fi, b)

    def _spacings(self, x, y, idx) -> None:
        """Distances between consecutive footprints (obs i, i + 1, both with a surface), from
        every SPACING_SAMPLE-th footprint: into the histogram."""
        i = np.arange(0, idx.size - 1, SPACING_SAMPLE)
        i = i[idx[i + 1] == idx[i] + 1]
        seg = np.hypot(x[idx[i + 1]] - x[idx[i]], y[idx[i + 1]] - y[idx[i]])
        seg = seg[seg > 0]
        if seg.size:
            k = (np.log10(seg) - _SPACING_DECADES[0]) * _SPACING_BINS_PER_DECADE + 1.0
            k = np.clip(k, 0, self.spacing_hist.size - 1).astype(np.int64)
            self.spacing_hist += np.bincount(k, minlength=self.spacing_hist.size)

    def add(self, fi: int, o0: int, x: np.ndarray, y: np.ndarray, track: np.ndarray) -> None:
        for b in range(x.shape[0]):
            self._add_beam(fi, b, o0, x[b], y[b], track[b])

    def _add_beam(self, fi, b, o0, x, y, track) -> None:
        idx = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        if idx.size == 0:
            return
        tb = track[idx]
        state = self._open.get((fi, b))
        # the footprint spacing, from the block's first points: the thinning looks at every
        # k-th footprint (vertices come every step, k spacings are an eighth of it at most)
        head = idx[:257]
        est = float(np.median(np.hypot(np.diff(x[head]), np.diff(y[head])))) if head.size > 1 \
            else self.step
        k = max(1, int(self.step / (8.0 * est))) if est > 0 else 1
        self._spacings(x, y, idx)
        # polylines start where the track changes, and where the footprints jump across a gap
        # (a beam off the terrain) by more than max(5 steps, 10 spacings)
        pt = state[0].track if state is not None else -2
        change = tb != np.concatenate([[pt], tb[:-1]])
        prev_obs = state[3] - o0 if state is not None else idx[0] - 1
        gap = np.flatnonzero(np.diff(idx, prepend=prev_obs) > 1)
        if gap.size:
            px = np.where(gap > 0, x[idx[np.maximum(gap - 1, 0)]], state[1] if state else 0.0)
            py = np.where(gap > 0, y[idx[np.maximum(gap - 1, 0)]], state[2] if state else 0.0)
            dist = np.hypot(x[idx[gap]] - px, y[idx[gap]] - py)
            change[gap[dist > max(5.0 * self.step, 10.0 * est)]] = True
        starts = np.flatnonzero(change)
        sample = np.unique(np.concatenate([np.arange(0, idx.size, k), starts,
                                           np.maximum(starts - 1, 0), [idx.size - 1]]))
        new_at = change[sample]
        xs, ys, ts, os_ = x[idx[sample]], y[idx[sample]], tb[sample], o0 + idx[sample]
        lx, ly = (state[1], state[2]) if state is not None else (xs[0], ys[0])
        seg = np.hypot(np.diff(xs, prepend=lx), np.diff(ys, prepend=ly))
        line = self._follows_a_line(xs, ys, seg)
        cuts = np.concatenate([[0], np.flatnonzero(new_at), [sample.size]])
        for a, z in zip(cuts[:-1], cuts[1:]):
            if z <= a:
                continue
            if new_at[a] or state is None:
                self._close(fi, b)
                pl = Polyline(fi, b, int(ts[a]))
                state = [pl, xs[a], ys[a], os_[a], 0.0]
                if pl.track >= 0:         # turns and transits (-1) keep no vertices
                    pl.x.append(float(xs[a])), pl.y.append(float(ys[a]))
                    pl.obs.append(int(os_[a]))
                lo = a + 1
            else:
                lo = a
            pl = state[0]
            if not line and pl.line:     # no vertices: a scan's would be every footprint
                pl.line = False
                pl.x, pl.y, pl.obs = pl.x[:1], pl.y[:1], pl.obs[:1]
            if pl.track >= 0 and pl.line and z > lo:
                cum = state[4] + np.cumsum(seg[lo:z])
                n_step = np.floor(cum / self.step)
                prev = np.concatenate([[np.floor(state[4] / self.step)], n_step[:-1]])
                sel = np.flatnonzero(n_step > prev)
                if sel.size:
                    pl.x.extend(xs[lo + sel].tolist()), pl.y.extend(ys[lo + sel].tolist())
                    pl.obs.extend(os_[lo + sel].tolist())
                state[4] = float(cum[-1])
            state[1], state[2], state[3] = xs[z - 1], ys[z - 1], os_[z - 1]
            self._open[(fi, b)] = state

    def _follows_a_line(self, xs, ys, seg) -> bool:
        """Whether a beam's footprints of a block follow a line: at most LINE_TURN_FRACTION of
        the turns between successive vertices (a step apart) exceed LINE_TURN_DEG (a conical
        scan, whose successive footprints lie across its circle, turns at every one)."""
        k = np.floor(np.cumsum(seg) / self.step)
        v = np.flatnonzero(np.diff(k, prepend=-1.0) > 0)
        if v.size < 4:
            return True
        dx, dy = np.diff(xs[v]), np.diff(ys[v])
        cross = dx[:-1] * dy[1:] - dy[:-1] * dx[1:]
        dot = dx[:-1] * dx[1:] + dy[:-1] * dy[1:]
        turn = np.abs(np.arctan2(cross, dot))
        return float(np.mean(turn > np.radians(LINE_TURN_DEG))) <= LINE_TURN_FRACTION

    def _close(self, fi: int, b: int) -> None:
        state = self._open.pop((fi, b), None)
        if state is None or state[0].track < 0 or not state[0].line:
            return
        pl = state[0]
        if pl.obs[-1] != state[3]:        # the track's last point ...
            if len(pl.x) > 1 and math.hypot(state[1] - pl.x[-1], state[2] - pl.y[-1]) \
                    < 0.5 * self.step:
                # ... replaces a vertex closer than half a step: a segment of a few footprints
                # would point wherever their pointing noise puts them
                del pl.x[-1], pl.y[-1], pl.obs[-1]
            pl.x.append(float(state[1])), pl.y.append(float(state[2]))
            pl.obs.append(int(state[3]))
        self.done.append(pl)

    def finish(self) -> list[Polyline]:
        for key in list(self._open):
            self._close(*key)
        return self.done


def _polyline_arrays(polylines):
    """Vertices of every polyline with >= 2 of them: x, y, obs, polyline id (concatenated)."""
    xs, ys, obs, pid = [], [], [], []
    for i, pl in enumerate(polylines):
        x, y, o = pl.arrays()
        if x.size < 2:
            continue
        xs.append(x), ys.append(y), obs.append(o), pid.append(np.full(x.size, i))
    if not xs:
        return (np.zeros(0),) * 2 + (np.zeros(0, np.int64),) * 2
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(obs), np.concatenate(pid)


def across_track_spacing(polylines) -> float:
    """Median over the thinned tracks' vertices of the distance to the nearest other track
    (another beam, line, pass or file): the nearest vertex with another label (k-d tree, k
    doubled until found), refined to the distance to its two segments."""
    from scipy.spatial import cKDTree

    x, y, _, pid = _polyline_arrays(polylines)
    keys = {}
    label = np.array([keys.setdefault((pl.file, pl.beam, pl.track), len(keys))
                      for pl in polylines], dtype=np.int64)
    if x.size == 0 or np.unique(label[pid]).size < 2:
        return float("nan")
    lab = label[pid]
    pts = np.column_stack([x, y])
    tree = cKDTree(pts)
    other = np.full(x.size, -1)
    # the median over at most ACROSS_TRACK_SAMPLES vertices, evenly strided
    todo = np.arange(0, x.size, max(1, x.size // ACROSS_TRACK_SAMPLES))
    k = 8
    while todo.size and k <= 4096:
        kk = min(k, x.size)
        _, nn = tree.query(pts[todo], k=kk)
        diff = lab[nn] != lab[todo][:, None]
        found = diff.any(axis=1)
        other[todo[found]] = nn[found, np.argmax(diff[found], axis=1)]
        todo = todo[~found]
        if kk == x.size:
            break
        k *= 4
    ok = other >= 0
    q, v = pts[ok], other[ok]
    best = np.hypot(*(q - pts[v]).T)
    for nb in (v - 1, v + 1):               # segments at the nearest vertex, same polyline
        good = (nb >= 0) & (nb < x.size)
        nb = np.where(good, nb, v)
        good &= pid[nb] == pid[v]
        a, b = pts[v], pts[nb]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                                     1e-300), 0.0, 1.0)
        dist = np.hypot(*(q - (a + t[:, None] * ab)).T)
        best = np.where(good, np.minimum(best, dist), best)
    return float(np.median(best)) if best.size else float("nan")


def _segment_crossings(polylines, step_m: float):
    """Candidate crossings of the thinned tracks: list of (polyline a, vertex index in a,
    polyline b, vertex index in b, x, y) with a's (file, track) != b's, crossing at
    ``MIN_CROSSING_ANGLE_DEG`` or more; one per pair of polylines within ``step_m``."""
    import shapely

    segs_x0, segs_y0, segs_x1, segs_y1, seg_pl, seg_k, n_seg = [], [], [], [], [], [], []
    for i, pl in enumerate(polylines):
        x, y, _ = pl.arrays()
        if x.size < 2:
            n_seg.append(0)
            continue
        segs_x0.append(x[:-1]), segs_y0.append(y[:-1]), segs_x1.append(x[1:])
        segs_y1.append(y[1:]), seg_pl.append(np.full(x.size - 1, i))
        seg_k.append(np.arange(x.size - 1))
        n_seg.append(x.size - 1)
    if not segs_x0:
        return []
    x0, y0 = np.concatenate(segs_x0), np.concatenate(segs_y0)
    x1, y1 = np.concatenate(segs_x1), np.concatenate(segs_y1)
    pl_of, k_of = np.concatenate(seg_pl), np.concatenate(seg_k)
    lines = shapely.linestrings(np.stack([np.column_stack([x0, y0]), np.column_stack([x1, y1])],
                                         axis=1))
    tree = shapely.STRtree(lines)
    i, j = tree.query(lines, predicate="intersects")
    keep = i < j
    i, j = i[keep], j[keep]
    ft = np.array([(pl.file, pl.track) for pl in polylines], dtype=np.int64)
    a, b = pl_of[i], pl_of[j]
    other = (ft[a, 0] != ft[b, 0]) | (ft[a, 1] != ft[b, 1])
    i, j = i[other], j[other]
    # the end of one leg of a waypoint path touches the start of the next: not a crossover
    a, b = pl_of[i], pl_of[j]
    last = np.array(n_seg) - 1
    consecutive = ((ft[a, 0] == ft[b, 0]) & (np.abs(ft[a, 1] - ft[b, 1]) == 1)
                   & (((k_of[i] == last[a]) & (k_of[j] == 0) & (ft[a, 1] < ft[b, 1]))
                      | ((k_of[j] == last[b]) & (k_of[i] == 0) & (ft[b, 1] < ft[a, 1]))))
    i, j = i[~consecutive], j[~consecutive]
    # tracks that run together (a repeat of a line) are not crossings: their crossing point is
    # not defined along track (its error is the across-track one over the sine of the angle)
    dx1, dy1 = x1[i] - x0[i], y1[i] - y0[i]
    dx2, dy2 = x1[j] - x0[j], y1[j] - y0[j]
    den = dx1 * dy2 - dy1 * dx2
    steep = np.abs(den) >= np.sin(np.radians(MIN_CROSSING_ANGLE_DEG)) * np.hypot(dx1, dy1) \
        * np.hypot(dx2, dy2)
    i, j, dx1, dy1, dx2, dy2, den = (v[steep] for v in (i, j, dx1, dy1, dx2, dy2, den))
    # crossing points of the segment pairs
    t = np.clip(((x0[j] - x0[i]) * dy2 - (y0[j] - y0[i]) * dx2) / den, 0.0, 1.0)
    px, py = x0[i] + t * dx1, y0[i] + t * dy1
    out = []
    seen: dict = {}
    for n in range(i.size):
        pa, pb = int(pl_of[i[n]]), int(pl_of[j[n]])
        key = (min(pa, pb), max(pa, pb))
        prev = seen.setdefault(key, [])
        if any(math.hypot(px[n] - qx, py[n] - qy) < step_m for qx, qy in prev):
            continue                                   # the same crossing through a vertex
        prev.append((px[n], py[n]))
        out.append((pa, int(k_of[i[n]]), pb, int(k_of[j[n]]), float(px[n]), float(py[n])))
    return out


_WINDOW_VARS = ("x", "y", "delta_time", "detected", "h_li", "h_li_true")


def _visit(win: dict, point) -> dict:
    """One track's visit of a crossing: time there and nearest detected shot."""
    from shapely.geometry import LineString

    ok = np.isfinite(win["x"]) & np.isfinite(win["y"])
    x, y, t = win["x"][ok], win["y"][ok], win["delta_time"][ok]
    out = {"time": np.nan, "h_li": np.nan, "h_li_true": np.nan, "distance": np.nan}
    if x.size >= 2:
        line = LineString(np.column_stack([x, y]))
        s = line.project(point)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
        out["time"] = float(np.interp(s, cum, t))
    elif x.size:
        out["time"] = float(t[0])
    det = (win["detected"] == 1) & ok
    if "h_li" in win:
        det &= np.isfinite(win["h_li"])
    if det.any():
        d = np.hypot(win["x"][det] - point.x, win["y"][det] - point.y)
        k = int(np.argmin(d))
        out["distance"] = float(d[k])
        out["h_li"] = float(win["h_li"][det][k])
        out["h_li_true"] = float(win["h_li_true"][det][k]) if "h_li_true" in win else np.nan
    return out


def _crossing_row(files, polylines, offset, pa, ka, pb, kb, x, y) -> tuple:
    """A crossing of polylines ``pa`` (segment ``ka``) and ``pb`` (``kb``) near (x, y), refined
    on their full-rate footprints: (x, y, earlier time, later time, earlier visit, later visit,
    earlier polyline, later polyline); ``offset``: each file's epoch offset [s]."""
    from shapely.geometry import LineString, Point

    sides = []
    for p, k in ((pa, ka), (pb, kb)):
        pl = polylines[p]
        _, _, obs = pl.arrays()
        lo, hi = int(obs[k]), int(obs[min(k + 1, obs.size - 1)])
        margin = max(2, hi - lo)
        sides.append((pl, files[pl.file].window(pl.beam, lo - margin, hi + margin + 1,
                                                _WINDOW_VARS)))
    point = Point(x, y)
    (pl1, w1), (pl2, w2) = sides
    ok1 = np.isfinite(w1["x"]) & np.isfinite(w1["y"])
    ok2 = np.isfinite(w2["x"]) & np.isfinite(w2["y"])
    if ok1.sum() >= 2 and ok2.sum() >= 2:
        fine = LineString(np.column_stack([w1["x"][ok1], w1["y"][ok1]])).intersection(
            LineString(np.column_stack([w2["x"][ok2], w2["y"][ok2]])))
        if not fine.is_empty:
            pts = [g for g in getattr(fine, "geoms", [fine])]
            cands = [q for g in pts for q in (
                [g] if g.geom_type == "Point" else [g.interpolate(0.5, normalized=True)])]
            point = min(cands, key=lambda q: q.distance(Point(x, y)))
    v1, v2 = _visit(w1, point), _visit(w2, point)
    t1 = v1["time"] + offset[pl1.file]
    t2 = v2["time"] + offset[pl2.file]
    if t2 < t1:
        (pl1, v1, t1), (pl2, v2, t2) = (pl2, v2, t2), (pl1, v1, t1)
    return (point.x, point.y, t1, t2, v1, v2, pl1, pl2)


def crossovers(files, polylines, cell_m: float, epsg: int) -> xr.Dataset:
    """The crossings of the tracks, refined on the full-rate footprints (definitions:
    :mod:`chirplidar.analysis.coverage`)."""
    step = cell_m / TRACK_STEP_PER_CELL
    epochs = [f.epoch for f in files]
    ref = min((e for e in epochs if e is not None), default=None)
    offset = [((e - ref).total_seconds() if (e is not None and ref is not None) else 0.0)
              for e in epochs]
    rows = [_crossing_row(files, polylines, offset, *crossing)
            for crossing in _segment_crossings(polylines, step)]
    n = len(rows)

    def col(fn, dtype=float):
        return np.array([fn(r) for r in rows], dtype=dtype) if n else np.zeros(0, dtype)

    xs, ys = col(lambda r: r[0]), col(lambda r: r[1])
    lat = lon = np.zeros(0)
    if n:
        from pyproj import Transformer

        lon, lat = Transformer.from_crs(epsg, 4326, always_xy=True).transform(xs, ys)
    since = f"seconds since {ref.isoformat().replace('+00:00', 'Z')}" if ref else "s"
    dims = ("crossover",)

    def var(values, units, long_name, **extra):
        return (dims, values, {"units": units, "long_name": long_name, **extra})

    h1, h2 = col(lambda r: r[4]["h_li"]), col(lambda r: r[5]["h_li"])
    g1, g2 = col(lambda r: r[4]["h_li_true"]), col(lambda r: r[5]["h_li_true"])
    ds = xr.Dataset({
        "time_1": var(col(lambda r: r[2]), since, "time of the earlier visit"),
        "time_2": var(col(lambda r: r[3]), since, "time of the later visit"),
        "time_between_visits": var(col(lambda r: r[3] - r[2]), "s",
                                   "time between the two visits"),
        "h_li_1": var(h1, "m", "h_li of the earlier track's detected shot nearest the crossing"),
        "h_li_2": var(h2, "m", "h_li of the later track's detected shot nearest the crossing"),
        "dh": var(h2 - h1, "m", "crossover height residual h_li_2 - h_li_1"),
        "dh_true": var(g2 - g1, "m", "h_li_true_2 - h_li_true_1 of the same shots (the part "
                                     "the footprints' offset on a sloping surface explains)"),
        "distance_1": var(col(lambda r: r[4]["distance"]), "m",
                          "distance from the crossing to the earlier track's nearest detected shot"),
        "distance_2": var(col(lambda r: r[5]["distance"]), "m",
                          "distance from the crossing to the later track's nearest detected shot"),
        "file_1": var(col(lambda r: r[6].file, np.int32), "1", "index of the earlier track's file"),
        "file_2": var(col(lambda r: r[7].file, np.int32), "1", "index of the later track's file"),
        "beam_1": var(col(lambda r: r[6].beam, np.int32), "1", "beam (trajectory) of the earlier track"),
        "beam_2": var(col(lambda r: r[7].beam, np.int32), "1", "beam (trajectory) of the later track"),
        "track_1": var(col(lambda r: r[6].track, np.int32), "1", "track (line or pass) number, earlier"),
        "track_2": var(col(lambda r: r[7].track, np.int32), "1", "track (line or pass) number, later"),
    }, coords={
        "x": var(xs, "m", "x of the crossing", standard_name="projection_x_coordinate"),
        "y": var(ys, "m", "y of the crossing", standard_name="projection_y_coordinate"),
        "latitude": var(np.asarray(lat, float), "degrees_north", "latitude of the crossing",
                        standard_name="latitude"),
        "longitude": var(np.asarray(lon, float), "degrees_east", "longitude of the crossing",
                         standard_name="longitude"),
    })
    ds.attrs.update({"featureType": "point", "files": json.dumps([str(f.path) for f in files]),
                     "epsg_code": f"EPSG:{epsg}"})
    return ds


def spacing_median(hist: np.ndarray) -> float:
    n = int(hist.sum())
    if n == 0:
        return float("nan")
    k = int(np.searchsorted(np.cumsum(hist), (n + 1) // 2))
    lo_dec = _SPACING_DECADES[0]
    return float(10 ** (lo_dec + (k - 0.5) / _SPACING_BINS_PER_DECADE))
