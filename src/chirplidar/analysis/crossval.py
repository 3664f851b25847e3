"""Cross-validation of the tiers: rf (reference) against baseband against link, case by case.

Each case is the thesis Chapter 5 homodyne bench (missions/thesis_ch5_bench.toml) with overrides:
the received power set for a target SNR, the range, the laser linewidth, a Doppler shift, speckle,
or a footprint of echoes. Every tier runs the same seeds, so the effects' draws (speckle, carrier
phase) are the same shot for shot and the comparison is paired; only the detector noise differs.

Reported per case and tier: mean SNR (dB); the fraction of shots whose range error exceeds
OUTLIER_M (a noise peak or a Doppler line won: a heavy tail that no RMS over a few hundred shots
estimates stably); range bias and range RMS of the other shots (m, against the true distance);
and the differences from rf. The peak search is limited to the baseband band
(``processing.peak_search_max_hz``) in every tier, so that at low SNR all tiers choose among the
same noise bins (the rf tier would otherwise search up to its 1.5 GHz Nyquist frequency and find
more false peaks than a receiver that digitises only the beat band).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..units import SPEED_OF_LIGHT_M_S

SEARCH_MAX_HZ = 100e6  # the chirp start frequency F1: the baseband tier's band top
OUTLIER_M = 1.0        # 11x the rf range RMS at 10 dB SNR on this bench (9 cm)


@dataclass(frozen=True)
class Case:
    """One cross-validation point: a name, the quantity varied and its value, overrides."""

    family: str
    label: str
    overrides: tuple[str, ...] = ()
    target_snr_db: float | None = None
    echoes: object | None = None
    tiers: tuple[str, ...] = ("rf", "baseband", "link")
    notes: str = field(default="", compare=False)


def _mission():
    from ..mission_files import default_mission_path
    return default_mission_path("thesis_ch5_bench.toml")


def distance_for_lag_m(lag_s: float, ref_delay_s: float = 106e-6, group_index: float = 1.458) -> float:
    """Fiber length (one way) whose round trip exceeds the reference delay by ``lag_s``."""
    return SPEED_OF_LIGHT_M_S * (ref_delay_s + lag_s) / (2 * group_index)


def pattn_for_snr(overrides, snr_db: float) -> float:
    """atm.Pattn that gives ``snr_db`` in the link tier (coherent SNR falls 1 dB per dB)."""
    from .. import load_mission, simulate_shot

    base = list(overrides) + ["atm.Pattn=60"]
    snr = simulate_shot(load_mission(_mission(), base), tier="link")["SNR"]
    return 60.0 + float(snr) - snr_db


def uniform_spread_echoes(spread_s: float, k: int = 9):
    """Echoes of a tilted footprint: k sub-returns spread uniformly over ``spread_s`` of round-trip
    delay with Gaussian beam weights (1/e^2 at the ends) and independent carrier phases (a diffuse
    surface: each patch is its own scatterer), drawn from a fixed generator."""
    from ..tiers.echoes import Echoes

    x = np.linspace(-1.0, 1.0, k)
    rng = np.random.default_rng(12345)
    return Echoes(delay_offset_s=0.5 * spread_s * x, power_weight=np.exp(-2 * x * x),
                  phase_rad=rng.uniform(0, 2 * np.pi, k))


def default_cases() -> list[Case]:
    """The published sweep: SNR 0-40 dB, range, linewidth, Doppler, speckle, footprint spread."""
    cases = [Case("snr", f"SNR {s:g} dB", target_snr_db=s) for s in (40, 30, 20, 10, 5, 0)]
    for lag in (1e-6, 12e-6):
        d = distance_for_lag_m(lag)
        cases.append(Case("range", f"beat {200e6 / 40e-6 * lag / 1e6:g} MHz ({d:.0f} m)",
                          (f"atm.dst={d}",), target_snr_db=20))
    for lw in (1e4, 1e5):
        cases.append(Case("linewidth", f"linewidth {lw / 1e3:g} kHz",
                          (f"lsr.Lw={lw}", 'effects.enabled=["phase_noise"]'), target_snr_db=25))
    for v in (0.5, 2.0):
        cases.append(Case("doppler", f"Doppler {2 * v / 1.31e-6 / 1e6:.2f} MHz",
                          ('effects.enabled=["doppler"]', f"effects.doppler.radial_velocity_mps={v}"),
                          target_snr_db=25))
    cases.append(Case("speckle", "speckle M = 1",
                      ('effects.enabled=["speckle"]', "effects.speckle.cells=1"), target_snr_db=25))
    for spread in (2e-9, 10e-9):
        cases.append(Case("footprint", f"footprint spread {spread * 1e9:g} ns",
                          target_snr_db=25, echoes=uniform_spread_echoes(spread),
                          tiers=("rf", "baseband")))
    return cases


def run_case(case: Case, *, n_rf: int, n_baseband: int, seed: int = 0) -> dict:
    """Run one case in each of its tiers; returns {tier: {snr_db, bias_m, rms_m, shots}}."""
    from .. import load_mission
    from ..channel.lab import simulate_lab

    base = [f"processing.peak_search_max_hz={SEARCH_MAX_HZ}", *case.overrides]
    if case.target_snr_db is not None:
        base.append(f"atm.Pattn={pattn_for_snr(base, case.target_snr_db)}")
    cfg = load_mission(_mission(), base)
    out = {}
    for tier in case.tiers:
        n = n_rf if tier == "rf" else n_baseband
        kw = {} if case.echoes is None else {"echoes": case.echoes}
        # Batches of 25 shots with seeds seed, seed + 1, ...: the same seeds in every tier.
        rows = [simulate_lab(cfg, tier, np.random.default_rng(seed + i), batch=min(25, n - 25 * i),
                             **kw)
                for i in range(-(-n // 25))]
        snr = np.concatenate([r["SNR"] for r in rows])
        err = np.concatenate([r["d_error"] for r in rows])
        inl = err[np.abs(err) <= OUTLIER_M]
        out[tier] = {"snr_db": float(np.mean(snr)), "outliers": float(1 - inl.size / err.size),
                     "bias_m": float(np.mean(inl)) if inl.size else np.nan,
                     "rms_m": float(np.sqrt(np.mean(inl ** 2))) if inl.size else np.nan,
                     "shots": int(err.size)}
    return out


def cross_validate(cases=None, *, n_rf: int = 200, n_baseband: int = 200, seed: int = 0,
                   progress=None) -> list[dict]:
    """Rows of the cross-validation table (one per case), differences taken from rf."""
    rows = []
    for case in cases or default_cases():
        res = run_case(case, n_rf=n_rf, n_baseband=n_baseband, seed=seed)
        ref = res["rf"]
        row = {"family": case.family, "case": case.label, "rf_snr_db": ref["snr_db"],
               "rf_outliers": ref["outliers"], "rf_bias_m": ref["bias_m"], "rf_rms_m": ref["rms_m"]}
        for tier in ("baseband", "link"):
            if tier in res:
                r = res[tier]
                row[f"{tier}_dsnr_db"] = r["snr_db"] - ref["snr_db"]
                row[f"{tier}_outliers"] = r["outliers"]
                row[f"{tier}_dbias_m"] = r["bias_m"] - ref["bias_m"]
                row[f"{tier}_rms_ratio"] = r["rms_m"] / ref["rms_m"] if ref["rms_m"] > 0 else np.nan
        rows.append(row)
        if progress:
            progress(row)
    return rows


def markdown_table(rows: list[dict]) -> str:
    """The table as Markdown (SNR in dB, outliers in %, bias in mm, RMS as tier over rf)."""
    head = ("| case | rf SNR (dB) | rf outliers | rf bias (mm) | rf RMS (mm) | baseband dSNR (dB) "
            "| baseband outliers | baseband dbias (mm) | baseband RMS / rf | link dSNR (dB) "
            "| link RMS / rf |")
    lines = [head, "|" + "---|" * 11]
    pct = lambda v: "—" if v is None else f"{100 * v:.0f} %"  # noqa: E731

    def fmt(v, scale=1.0, spec="{:+.2f}"):
        return "—" if v is None or not np.isfinite(v) else spec.format(v * scale)

    for r in rows:
        lines.append(
            f"| {r['case']} | {r['rf_snr_db']:.1f} | {pct(r['rf_outliers'])} | "
            f"{fmt(r['rf_bias_m'], 1e3, '{:+.1f}')} | {fmt(r['rf_rms_m'], 1e3, '{:.1f}')} | "
            f"{fmt(r.get('baseband_dsnr_db'))} | {pct(r.get('baseband_outliers'))} | "
            f"{fmt(r.get('baseband_dbias_m'), 1e3, '{:+.1f}')} | "
            f"{fmt(r.get('baseband_rms_ratio'), 1.0, '{:.2f}')} | {fmt(r.get('link_dsnr_db'))} | "
            f"{fmt(r.get('link_rms_ratio'), 1.0, '{:.2f}')} |")
    return "\n".join(lines) + "\n"


def write_table(rows: list[dict], path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(markdown_table(rows))
    return path


def main(argv=None) -> int:
    """``python -m chirplidar.analysis.crossval [--out docs/explanation/validation/crossval.md] [--n-rf N]``."""
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="outputs/crossval.md", help="Markdown table to write")
    p.add_argument("--n-rf", type=int, default=400, help="rf shots per case (baseband, link: 4x)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    if a.n_rf < 1:
        p.error("--n-rf must be >= 1")
    rows = cross_validate(n_rf=a.n_rf, n_baseband=4 * a.n_rf, seed=a.seed,
                          progress=lambda r: print(f"  {r['case']}", flush=True))
    print(markdown_table(rows))
    print(f"wrote {write_table(rows, a.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
