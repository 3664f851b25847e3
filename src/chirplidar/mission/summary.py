"""The summary of a run: counts of the ``detected`` flag, the detected shots' median SNR and
range-error statistics, from the results in memory (:func:`summarise`) or streamed over a
run's chunk files in bounded memory (:func:`summary_of_chunks`), and its text
(:func:`format_summary`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .results import DETECTED_FLAG_VALUES, NETCDF_LOCK

#: The codes of the ``detected`` flag the summary counts (0 .. 5).
N_DETECTED_CODES = DETECTED_FLAG_VALUES.size


def summarise(ds, path, elapsed_s: float) -> dict:
    """Summary of a results dataset in memory (the reference for :func:`summary_of_chunks`)."""
    det = ds["detected"].values
    err = ds["range_error"].values[det == 1]
    snr = ds["snr_db"].values[det == 1]
    n_obs = int(ds.sizes["obs"])
    return {
        "output": str(path), "tier": ds.attrs.get("tier", ""), "seed": int(ds.attrs["seed"]),
        "beams": int(ds.sizes["trajectory"]), "shots": n_obs,
        "returns": int(det.size), "detected": int(np.sum(det == 1)),
        "below_threshold": int(np.sum(det == 0)), "no_surface": int(np.sum(det == 2)),
        "outside_range_gate": int(np.sum(det == 3)), "doppler_displaced": int(np.sum(det == 4)),
        "range_ambiguous": int(np.sum(det == 5)),
        "median_snr_db": float(np.median(snr)) if snr.size else float("nan"),
        "range_error_mean_m": float(np.mean(err)) if err.size else float("nan"),
        "range_error_std_m": float(np.std(err)) if err.size else float("nan"),
        "range_error_rms_m": float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan"),
        "range_error_p95_abs_m": (float(np.percentile(np.abs(err), 95)) if err.size
                                  else float("nan")),
        "elapsed_s": elapsed_s,
    }


_SIGN = np.uint64(1 << 63)


def _sortable_keys(x: np.ndarray) -> np.ndarray:
    """uint64 keys in the order of the (finite) float64 values ``x``."""
    b = np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)
    return np.where(b & _SIGN, ~b, b | _SIGN)


def _key_value(key: int) -> float:
    k = np.uint64(key)
    b = k ^ _SIGN if k & _SIGN else ~k
    return float(np.array([b], dtype=np.uint64).view(np.float64)[0])


def order_statistics(blocks, ranks: list[list[int]], first_pass=None) -> list[list[float]]:
    """Exact order statistics of several streams, with memory bounded by one block.

    ``blocks()`` yields, per block, a tuple of 1-D float64 arrays (one per stream, finite
    values) and is re-iterated; ``ranks[s]`` are 0-based ranks into the sorted union of stream
    ``s``. A 4-pass radix select on 16-bit digits of order-preserving uint64 keys (2^16 counters
    per rank). ``first_pass(block)``, if given, is also called on every block of the first pass.
    """
    prefix = [[0] * len(r) for r in ranks]
    left = [list(r) for r in ranks]
    for shift in (48, 32, 16, 0):
        hist = [[np.zeros(1 << 16, dtype=np.int64) for _ in r] for r in ranks]
        for block in blocks():
            if shift == 48 and first_pass is not None:
                first_pass(block)
            for s, x in enumerate(block):
                if not ranks[s]:
                    continue
                keys = _sortable_keys(x)
                for j in range(len(ranks[s])):
                    sel = keys if shift == 48 else keys[
                        (keys >> np.uint64(shift + 16)) == np.uint64(prefix[s][j] >> (shift + 16))]
                    digit = ((sel >> np.uint64(shift)) & np.uint64(0xFFFF)).astype(np.int64)
                    hist[s][j] += np.bincount(digit, minlength=1 << 16)
        for s in range(len(ranks)):
            for j in range(len(ranks[s])):
                c = np.cumsum(hist[s][j])
                d = int(np.searchsorted(c, left[s][j], side="right"))
                left[s][j] -= int(c[d - 1]) if d else 0
                prefix[s][j] |= d << shift
    return [[_key_value(p) for p in ps] for ps in prefix]


def quantile_ranks(n: int, q: float) -> tuple[int, int, float]:
    """``np.percentile``'s linear method on n sorted values: (lower rank, upper rank, weight of
    the upper); :func:`quantile_between` of the two order statistics is the quantile q."""
    v = (n - 1) * q
    lo = min(math.floor(v), n - 1)
    hi = min(lo + 1, n - 1)
    return lo, hi, (0.0 if v >= n - 1 else v - lo)


def quantile_between(a: float, b: float, g: float) -> float:
    """numpy's linear interpolation between the order statistics a <= b with weight g of b
    (its rounding: from b downwards when g >= 1/2)."""
    diff = b - a
    return b - diff * (1 - g) if g >= 0.5 else a + diff * g


#: The chunk variables the summary reads.
SUMMARY_VARIABLES = ("detected", "snr_db", "range_error")


class SummaryPass:
    """First pass of :func:`summary_of_chunks`, fed chunk by chunk in chunk order with the
    stored ``detected``, ``snr_db`` and ``range_error`` values: counts, sums, and the detected
    shots' SNR and range errors while they fit in ``budget_bytes``.

    With a ``spill_dir``, the detected shots' SNR and range errors that do not fit are
    appended to two raw float64 files there instead (:meth:`spilled_blocks` reads them back
    in blocks of the budget), so that the later passes read 16 bytes per detected shot
    instead of decompressing the chunk files again."""

    def __init__(self, n_beams: int, budget_bytes: int, spill_dir=None):
        self.n_beams, self.budget_bytes = n_beams, budget_bytes
        self.n_obs = 0
        self.counts = np.zeros(N_DETECTED_CODES, dtype=np.int64)
        self.s1 = self.s2 = 0.0
        self.kept: list | None = []
        self.spill_dir = None if spill_dir is None else Path(spill_dir)
        self.spilled = False

    def _spill_paths(self) -> tuple[Path, Path]:
        if self.spill_dir is None:
            raise ValueError("this summary pass has no spill_dir")
        return self.spill_dir / "summary_snr.f8", self.spill_dir / "summary_err.f8"

    def _spill(self, pairs, mode: str) -> None:
        for path, k in zip(self._spill_paths(), (0, 1), strict=True):
            with open(path, mode) as fh:
                for pair in pairs:
                    pair[k].tofile(fh)

    def spilled_blocks(self):
        """(SNR, range error) of the detected shots, spilled, in blocks of the budget."""
        paths = self._spill_paths()
        n = max(1, self.budget_bytes // 16)
        with open(paths[0], "rb") as fs, open(paths[1], "rb") as fe:
            while True:
                snr, err = np.fromfile(fs, np.float64, n), np.fromfile(fe, np.float64, n)
                if not snr.size:
                    return
                yield snr, err

    @staticmethod
    def detected_columns(det, snr, err):
        """(detected flags, SNR and range errors of the detected shots), flattened."""
        det = np.asarray(det).ravel()
        ok = det == 1
        return (det, np.asarray(snr).ravel()[ok].astype(np.float64),
                np.asarray(err).ravel()[ok].astype(np.float64))

    def add(self, det, snr, err) -> None:
        det, snr, err = self.detected_columns(det, snr, err)
        self.n_obs += det.size // max(self.n_beams, 1)
        self.counts += np.bincount(det.astype(np.int64),
                                   minlength=N_DETECTED_CODES)[:N_DETECTED_CODES]
        self.s1 += float(np.sum(err))
        self.s2 += float(np.sum(err * err))
        if self.spilled:
            self._spill([(snr, err)], "ab")
        elif self.kept is not None:
            self.kept.append((snr, err))
            if 16 * int(self.counts[1]) > self.budget_bytes:
                if self.spill_dir is not None:
                    self._spill(self.kept, "wb")
                    self.spilled = True
                self.kept = None


def summary_of_chunks(files: list[Path], path, tier: str, seed: int, n_beams: int,
                       elapsed_s: float, budget_bytes: int,
                       first_pass: SummaryPass | None = None) -> dict:
    """:func:`summarise` of the run whose chunk files are ``files``, chunk by chunk, in memory
    bounded by ``budget_bytes`` (the run passes one chunk's size).

    The detected shots' SNR and range errors are kept while they fit in the budget; then the
    statistics are numpy's own (as :func:`summarise`). Beyond it they are streamed: counts
    and quantiles exactly as numpy's (``np.median``; ``np.percentile``, linear method) from
    :func:`order_statistics`, mean, standard deviation and RMS as sums over chunks (last-bit
    differences from numpy's pairwise sums); five passes over the chunk files, or over the
    first pass's spill files when it has them.
    ``first_pass``: the first pass, already fed with every chunk (a run feeds it while it
    appends chunks to the results file); without it the files are read.
    """
    import netCDF4

    def stored():
        for f in files:
            with NETCDF_LOCK, netCDF4.Dataset(f) as src:
                cols = []
                for name in SUMMARY_VARIABLES:
                    v = src[name]
                    v.set_auto_maskandscale(False)
                    cols.append(v[...])
            yield cols

    def columns():
        if first_pass.spilled:
            return ((None, snr, err) for snr, err in first_pass.spilled_blocks())
        return (SummaryPass.detected_columns(*cols) for cols in stored())

    if first_pass is None:
        first_pass = SummaryPass(n_beams, budget_bytes)
        for cols in stored():
            first_pass.add(*cols)
    n_obs, counts, kept = first_pass.n_obs, first_pass.counts, first_pass.kept
    s1, s2 = first_pass.s1, first_pass.s2
    n_det = int(counts[1])
    nan = float("nan")
    median = mean = std = rms = p95 = nan
    if n_det and kept is not None:
        snr = np.concatenate([k[0] for k in kept])
        err = np.concatenate([k[1] for k in kept])
        median, mean, std = np.median(snr), np.mean(err), np.std(err)
        rms, p95 = np.sqrt(np.mean(err ** 2)), np.percentile(np.abs(err), 95)
    elif n_det:
        mean = s1 / n_det
        rms = math.sqrt(s2 / n_det)
        # np.median: the middle value or the mean of the middle two.
        mid = [n_det // 2] if n_det % 2 else [n_det // 2 - 1, n_det // 2]
        lo, hi, g = quantile_ranks(n_det, 0.95)     # np.percentile(.., 95), linear method
        dev = [0.0]

        def add_dev(block):
            dev[0] += float(np.sum((block[2] - mean) ** 2))

        snr_q, err_q, _ = order_statistics(
            lambda: ((snr, np.abs(err), err) for _, snr, err in columns()), [mid, [lo, hi], []],
            add_dev)
        std = math.sqrt(dev[0] / n_det)
        median = snr_q[0] if len(mid) == 1 else (snr_q[0] + snr_q[1]) / 2
        p95 = quantile_between(*err_q, g)
    return {
        "output": str(path), "tier": tier, "seed": int(seed), "beams": int(n_beams),
        "shots": int(n_obs), "returns": int(n_obs * n_beams), "detected": n_det,
        "below_threshold": int(counts[0]), "no_surface": int(counts[2]),
        "outside_range_gate": int(counts[3]), "doppler_displaced": int(counts[4]),
        "range_ambiguous": int(counts[5]),
        "median_snr_db": float(median), "range_error_mean_m": float(mean),
        "range_error_std_m": float(std), "range_error_rms_m": float(rms),
        "range_error_p95_abs_m": float(p95), "elapsed_s": elapsed_s,
    }


def format_summary(s: dict) -> str:
    """The summary ``s`` as the lines ``chirplidar run`` prints."""
    pct = 100.0 * s["detected"] / s["returns"] if s["returns"] else 0.0
    lines = [
        f"chirplidar run: {s['shots']} shots x {s['beams']} beam(s), tier {s['tier']}, "
        f"seed {s['seed']}, {s['elapsed_s']:.1f} s",
        f"  detected         {s['detected']} of {s['returns']} ({pct:.1f} %); "
        f"{s['below_threshold']} below threshold, {s['no_surface']} with no surface in the beam"
        + "".join(f", {s[k]} {text}" for k, text in (
            ("outside_range_gate", "outside the range gate (window or processed band)"),
            ("doppler_displaced", "displaced by an uncompensated Doppler shift"),
            ("range_ambiguous", "ambiguous by a chirp period (reference delay)")) if s.get(k)),
    ]
    if s["detected"]:
        lines += [
            f"  median SNR       {s['median_snr_db']:.1f} dB (detected shots)",
            f"  range error      mean {s['range_error_mean_m'] * 100:.2f} cm, std "
            f"{s['range_error_std_m'] * 100:.2f} cm, RMS {s['range_error_rms_m'] * 100:.2f} cm, "
            f"95 % |err| < {s['range_error_p95_abs_m'] * 100:.2f} cm"]
    else:
        lines.append("  no shot detected: no SNR or range-error statistics")
    lines.append(f"  output           {s['output']}")
    return "\n".join(lines)
