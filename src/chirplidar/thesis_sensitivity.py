"""Thesis Fig. 5.7 reproduction (``chirplidar sensitivity``): SNR against received power for
self-chirped homodyne, direct and heterodyne detection on the lab-bench mission, with the measured
points of Tables 5.2-5.4.

Each detection type is one sweep of the bench attenuator ``atm.Pattn`` (dB). On the fiber bench
the received power is Psig = Psig(Pattn=0) - Pattn (dBm), so one probe shot at Pattn = 0 fixes the
attenuations that put each curve over the thesis's measured power range.
"""

from __future__ import annotations

import csv
import io
import math
import sys
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

from .analysis import sensitivity_at
from .units import PLANCK_J_S, SPEED_OF_LIGHT_M_S, db_to_ratio, ratio_db

PNG_NAME = "fig5_7_sensitivity.png"
CSV_NAME = "fig5_7_sensitivity.csv"
SNR_LEVEL_DB = 10.0  # the thesis's sensitivity criterion


@dataclass(frozen=True)
class Detection:
    """One curve of Fig. 5.7: ``--set`` overrides, target Psig span (dBm, strong to weak) and the
    thesis's measured sensitivity at 10 dB SNR (dBm) with its table."""
    name: str
    overrides: tuple[str, ...]
    psig_span_dbm: tuple[float, float]
    measured_10db_dbm: float
    table: str


# Run on missions/thesis_ch5_bench.toml (the measured hardware). The homodyne modulator sits at
# its null (Sec. 3.1, set in the mission); the direct and heterodyne prototypes need power
# modulation at the chirp frequency, i.e. the linear-power bias V_pi / 2 (Fig. 2.10 left).
SENSITIVITY_MISSION = "thesis_ch5_bench.toml"

DETECTIONS: tuple[Detection, ...] = (
    Detection("homodyne", (), (-40.0, -110.0), -96.0, "5.4"),
    Detection("direct", ("sys.rsel=PIN", "mzm.Vdc=1.0"), (-15.0, -50.0), -40.0, "5.2"),
    Detection("heterodyne", ("sys.CxMode=het", "mzm.Vdc=1.0"), (-25.0, -80.0), -70.0, "5.3"),
)


@dataclass
class CurveResult:
    """Simulated curve of one detection type: attenuations (dB), outputs per point, sensitivity."""
    detection: Detection
    pattn_db: np.ndarray
    outputs: dict[str, np.ndarray]          # Table 4.10 name -> values per point (repeat 0)
    psig0_dbm: float                        # Psig at Pattn = 0 (dBm)
    ptx_dbm: float                          # Ptx (dBm)
    psig_10db_dbm: float                    # simulated sensitivity (dBm), nan if not crossed
    note: str = ""
    flags: list[str] = field(default_factory=list)  # comma-separated flags per point


@dataclass
class SensitivityResult:
    png: Path
    csv: Path
    curves: list[CurveResult]
    tier: str
    seconds: float
    shot_noise_10db_dbm: float
    notes: list[str] = field(default_factory=list)


def load_measured() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Thesis Tables 5.2-5.4 from the packaged CSV: detection -> (Pin in dBm, SNR in dB)."""
    text = (resources.files("chirplidar") / "data" / "thesis_sensitivity.csv").read_text()
    rows = csv.DictReader(line for line in io.StringIO(text) if not line.lstrip().startswith("#"))
    data: dict[str, list[tuple[float, float]]] = {}
    for row in rows:
        data.setdefault(row["detection"].strip(), []).append(
            (float(row["pin_dbm"]), float(row["snr_db"])))
    return {det: (np.array([p for p, _ in pts]), np.array([s for _, s in pts]))
            for det, pts in data.items()}


def shot_noise_snr_db(p_dbm, quantum_efficiency: float = 0.85, wavelength_m: float = 1.31e-6,
                      bandwidth_hz: float = 30e3):
    """Shot-noise-limited coherent SNR (dB), thesis eq. 2.6.2: SNR = eta P / (2 h nu B)."""
    p_w = db_to_ratio(np.asarray(p_dbm, dtype=float) - 30.0)
    h_nu = PLANCK_J_S * SPEED_OF_LIGHT_M_S / wavelength_m
    return ratio_db(quantum_efficiency * p_w / (2.0 * h_nu * bandwidth_hz))


def shot_noise_power_dbm(snr_db: float, quantum_efficiency: float = 0.85,
                         wavelength_m: float = 1.31e-6, bandwidth_hz: float = 30e3) -> float:
    """Received power (dBm) at which eq. 2.6.2 gives ``snr_db``."""
    return float(snr_db - shot_noise_snr_db(0.0, quantum_efficiency, wavelength_m, bandwidth_hz))


def _fmt(value: float) -> str:
    return repr(float(value)) if math.isfinite(value) else ("-inf" if value < 0 else "inf"
                                                           if value > 0 else "nan")


def write_csv(path: Path, curves: list[CurveResult], names: Sequence[str], units: dict[str, str],
              header: str) -> Path:
    """The simulated points, one row per (detection, Pattn); '#' lines carry units and settings.

    Non-finite values are written as ``-inf``/``inf``; ``flags`` is comma-separated (quoted)."""
    with open(path, "w", newline="") as fh:
        for line in header.splitlines():
            fh.write(f"# {line}\n")
        fh.write("# units: atm.Pattn dB; " + "; ".join(f"{n} {units.get(n, '')}" for n in names)
                 + "\n")
        writer = csv.writer(fh)
        writer.writerow(["detection", "atm.Pattn", *names, "flags"])
        for c in curves:
            for k, pattn in enumerate(c.pattn_db):
                writer.writerow([c.detection.name, _fmt(pattn),
                                 *(_fmt(c.outputs[n][k]) for n in names),
                                 c.flags[k] if k < len(c.flags) else ""])
    return path


def run_sensitivity(out_dir: str | Path = "outputs", tier: str = "rf", points: int = 14,
             mission: str | Path | None = None, seed: int | None = 1, progress: bool = True,
             detections: Sequence[Detection] = DETECTIONS) -> SensitivityResult:
    """Run the three Fig. 5.7 sweeps, write ``out_dir/fig5_7_sensitivity.{png,csv}``.

    ``points`` attenuation steps per curve, ``tier`` the transceiver tier, ``seed`` the run seed.
    Progress (stage messages and tqdm bars) goes to stderr when ``progress`` is true.
    """
    from .api import OUTPUT_NAMES, OUTPUT_UNITS, simulate_shot, sweep
    from .config import ConfigError, config_with, load_mission
    from .mission_files import default_mission_path

    if points < 2:
        raise ValueError(f"points must be >= 2, got {points}")
    t0 = time.perf_counter()
    mission = Path(mission) if mission is not None else default_mission_path(SENSITIVITY_MISSION)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []

    def say(msg: str) -> None:
        if progress:
            print(msg, file=sys.stderr, flush=True)

    # Validate every curve's configuration before spending time on any of them.
    configs = []
    for det in detections:
        try:
            configs.append(load_mission(mission, list(det.overrides)))
        except ConfigError as exc:
            what = " ".join(det.overrides) or "mission defaults"
            raise ConfigError(f"sensitivity curve '{det.name}' ({what}): {exc}") from None

    curves: list[CurveResult] = []
    for det, cfg in zip(detections, configs):
        # The link tier's budget of the unattenuated channel (no draw, no warning about the
        # receiver saturating at a power the sweep never reaches).
        probe = simulate_shot(config_with(cfg, {"atm.Pattn": 0.0}), seed=seed, tier="link")
        psig0, ptx = float(probe["Psig"]), float(probe["Ptx"])
        if not math.isfinite(psig0):
            raise RuntimeError(f"{det.name}: the probe shot at atm.Pattn=0 received no power "
                               f"(Psig = {psig0}); cannot place the sweep")
        hi, lo = det.psig_span_dbm
        start, stop = psig0 - hi, psig0 - lo
        if start < 0.0:
            notes.append(f"{det.name}: Psig at Pattn=0 is {psig0:.1f} dBm, below the target "
                         f"{hi:g} dBm; sweep starts at Pattn=0")
            start = 0.0
        say(f"[sensitivity] {det.name}: Ptx {ptx:.2f} dBm, Psig(Pattn=0) {psig0:.2f} dBm; "
            f"sweeping atm.Pattn {start:.1f}..{stop:.1f} dB in {points} points ({tier} tier)")
        ds = sweep(cfg, "atm.Pattn", start, stop, points, repeat=1, scale="lin", seed=seed,
                   tier=tier, progress=progress)
        outputs = {n: np.asarray(ds[n].transpose("x", ...).values, dtype=float).reshape(
            ds.sizes["x"], -1)[:, 0] for n in OUTPUT_NAMES}
        p10, slope, used = sensitivity_at(outputs["Psig"], outputs["SNR"], SNR_LEVEL_DB)
        note = (f"line fit over SNR 12-40 dB, {used} points, slope {slope:.2f} dB/dB"
                if used >= 3 else f"only {used} points with SNR 12-40 dB: no fit")
        flags = ([str(v) for v in ds["flags"].values.reshape(ds.sizes["x"], -1)[:, 0]]
                 if "flags" in ds.data_vars else [""] * ds.sizes["x"])
        curves.append(CurveResult(det, np.asarray(ds["x"].values, dtype=float), outputs, psig0,
                                  ptx, p10, note, flags))

    from .viz.sensitivity import plot_sensitivity

    measured = load_measured()
    p_line = np.linspace(-115.0, -10.0, 211)
    png = plot_sensitivity(
        out_dir / PNG_NAME,
        {c.detection.name: (c.outputs["Psig"], c.outputs["SNR"]) for c in curves},
        {c.detection.name: measured[c.detection.name] for c in curves
         if c.detection.name in measured},
        shot_noise=(p_line, shot_noise_snr_db(p_line)),
        shot_noise_label="shot-noise limit, eq. 2.6.2 (eta 0.85, B 30 kHz, 1.31 um)",
        snr_line_db=SNR_LEVEL_DB,
        title=f"Thesis Fig. 5.7: sensitivity, simulated ({tier} tier) vs measured")
    header = (f"chirplidar sensitivity: thesis Fig. 5.7 sensitivity sweeps of atm.Pattn\n"
              f"mission {mission}; tier {tier}; seed {seed}; points {points}")
    csv_path = write_csv(out_dir / CSV_NAME, curves, list(OUTPUT_NAMES), dict(OUTPUT_UNITS), header)
    return SensitivityResult(png, csv_path, curves, tier, time.perf_counter() - t0,
                      shot_noise_power_dbm(SNR_LEVEL_DB), notes)


def format_summary(result: SensitivityResult) -> str:
    """Table of simulated against measured sensitivity (Psig at 10 dB SNR, dBm), read from a line
    fitted over SNR 12-40 dB (:func:`chirplidar.analysis.sensitivity_at`), as the tests read it."""
    lines = [f"Sensitivity at {SNR_LEVEL_DB:g} dB SNR (Psig, dBm), {result.tier} tier:",
             f"  {'detection':<11} {'simulated':>10} {'measured':>9}  {'diff':>6}  source"]
    for c in result.curves:
        sim = f"{c.psig_10db_dbm:10.1f}" if math.isfinite(c.psig_10db_dbm) else f"{'n/a':>10}"
        diff = c.psig_10db_dbm - c.detection.measured_10db_dbm
        dtxt = f"{diff:+6.1f}" if math.isfinite(diff) else f"{'':>6}"
        lines.append(f"  {c.detection.name:<11} {sim} {c.detection.measured_10db_dbm:9.1f}  "
                     f"{dtxt}  thesis Table {c.detection.table}"
                     + (f"  ({c.note})" if c.note else ""))
    lines.append(f"  {'shot-noise limit (eq. 2.6.2)':<29} {result.shot_noise_10db_dbm:.1f} dBm")
    lines.extend(f"  note: {n}" for n in result.notes)
    lines.append(f"Wrote {result.png} and {result.csv} in {result.seconds:.1f} s")
    return "\n".join(lines)
