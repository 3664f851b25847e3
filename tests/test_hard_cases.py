"""The hard-case catalogue (DESIGN.md, "Hard cases that must stay stable"; issue 15, item 7).

``CASES`` lists every hard case once: what it is, how it is built (a shipped mission and
``--set`` overrides, or a small survey written to a temporary folder), the tiers that support
it and the outcome expected of it. ``test_hard_case`` runs each (case, tier) in this process
(``chirplidar shot --json`` for the link and rf tiers, :func:`chirplidar.api.simulate_shot` for
the baseband tier, which the command line's ``shot`` does not offer; ``chirplidar run`` for the
surveys) and asserts

* the invariant every outcome obeys: every number is finite, or it is null / NaN and a flag
  says why (a shot: a flag whose definition nulls that output, ``tiers.common.null_unmeasured``;
  a survey: ``detected != 1`` on that shot), never a sentinel value (-300 dB, the netCDF
  default fill, ...), never a beat outside the processed band without ``beat_out_of_band``
  (the flag's definition); a refusal is exit 2 and one line (the command line) or a
  ValueError naming the problem (the API), never a traceback;
* the case's own expected outcome: a refusal (its message), flags and nulls, survey
  ``detected`` codes, or a plain valid result, with the extra checks each names the source of.

Cases that another test module already runs (faults, chunks, locks, a full disk, no workers,
NaN / inf in any input, ...) are rows that point to those tests; ``test_pointers_exist``
checks that each pointed-to test still exists.

``render_markdown`` writes the table of the cases and their observed outcomes;
``test_docs_table_is_current`` asserts docs/hard_cases.md equals it (the outcomes come from
running the cases), and ``CHIRPLIDAR_WRITE_DOCS=1 .venv/bin/python -m pytest
tests/test_hard_cases.py`` rewrites it.

A (case, tier) that exposes a bug is marked ``xfail(strict=True)`` with the bug in its reason.
"""

from __future__ import annotations

import ast
import contextlib
import io
import json
import math
import os
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from conftest import (
    BENCH,
    CH5,
    write_flat_uav_mission,
    write_scene,
    write_uav_mission,
)

from chirplidar.api import OUTPUT_NAMES, simulate_shot
from chirplidar.cli import main
from chirplidar.config import load_mission
from chirplidar.mission.results import (
    DETECTED_FLAG_MEANINGS,
    NOT_MEASURED_BY,
    SCHEMA_BY_NAME,
    read_netcdf,
)
from chirplidar.channel.lab import lab_budget
from chirplidar.units import SPEED_OF_LIGHT_M_S

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "explanation" / "validation" / "hard_cases.md"
ICESAT = ROOT / "missions" / "icesat_like.toml"
TIERS = ("link", "baseband", "rf")
WRITE_DOCS_ENV = "CHIRPLIDAR_WRITE_DOCS"

# Table 4.10 outputs a tier may null (JSON) when it cannot stand behind them, grouped as
# tiers.common groups them: where the beat is, the range read from it, the spectrum's peak.
BEAT = ("f_beat_hz", "d_rx", "d_lo", "d_hi", "d_error", "d_3dB")
RANGE = ("d_rx", "d_lo", "d_hi", "d_error")
PEAK = ("Crx", "SNR", "d_res")
SHOT_KEYS = (*OUTPUT_NAMES, "f_beat_hz")
# What each flag's definition nulls (tiers.common.null_unmeasured and assemble_outputs: zero
# received power reads Psig = -inf dBm; no chirp drive Pchrp = -inf dBm, and at the modulator's
# null no light: Ptx = Psig = -inf dBm; silent shots Crx = SNR = -inf, d_res = inf; off-band
# shots no beat, and in the spectrum tiers no peak; ambiguous shots no range). The other flags
# (saturation, doppler_ambiguous, fiber_acceptance_exceeded, squaring_recovery) null nothing.
EXPLAINS = {
    "no_return": (*BEAT, *PEAK, "Psig"),
    "no_lo": (*BEAT, *PEAK),
    "no_chirp": (*BEAT, *PEAK, "Pchrp", "Ptx", "Psig"),   # no drive: at the null, no light
    "no_overlap": (*BEAT, *PEAK),
    "beat_out_of_band": (*BEAT, *PEAK),
    "beat_above_nyquist": (*BEAT, *PEAK),
    "range_ambiguous": RANGE,
    "next_chirp_tone": (*BEAT, *PEAK),   # the tone read is the next chirp's, not this lag's
    "harmonic_beat": (*BEAT, *PEAK),     # the tone read is at 2 f_R, the modulator's harmonic
}
# Sentinels a "no value" was once written as (-300 dB), fills of other conventions, the netCDF
# default float fill: never a value of a shot or a results file.
SENTINELS = (-300.0, 300.0, -999.0, -9999.0, 9999.0, -99999.0, 1e20, -1e20, 1e30, -1e30,
             9.969209968386869e36, 3.4028234663852886e38, -3.4028234663852886e38)
CODE_NAMES = dict(enumerate(DETECTED_FLAG_MEANINGS.split()))
DETECTION_THRESHOLD_DB = 10.0   # survey.detection_threshold_db of the shipped missions (Table 5.4)
# 30 dB more received power than the field instrument's, at the optimum carrier phase.
LOUD = ("channel.extra_attenuation_db=-30", "channel.carrier_phase=optimal")


# ------------------------------------------------------------------ derived overrides

def _ptx_dbm(mission=CH5, extra=()):
    """Transmitted power [dBm] of a bench (link tier: a closed form, no draw)."""
    return simulate_shot(load_mission(mission, list(extra)), tier="link")["Ptx"]


def _dst_at_lag(lag_s, extra=()):
    """atm.dst [m] of the Chapter 5 bench whose delay is tau_ref + lag_s: tau = 2 n R / c."""
    cfg = load_mission(CH5, list(extra))
    return (cfg.system.reference_delay_s + lag_s) * SPEED_OF_LIGHT_M_S / (2 * cfg.channel.group_index)


def _period_m():
    """c T / (2 n): the range of one chirp period of the Chapter 5 bench."""
    cfg = load_mission(CH5)
    return SPEED_OF_LIGHT_M_S * lab_budget(cfg).train.period_s / (2 * cfg.channel.group_index)


WAVELENGTH_M = 1.31e-6   # thesis Table 4.4 lsr.Lo
D_TEL_M = 0.2032         # thesis Table 4.6 atm.D_tel


def _cn2_for(d_over_r0, path_m):
    """atm.Cn2 whose plane-wave Fried parameter r0 = (0.423 k^2 Cn2 L)^(-3/5) (Fried 1966) is
    D_tel / d_over_r0 over ``path_m``."""
    k = 2 * np.pi / WAVELENGTH_M
    return (D_TEL_M / d_over_r0) ** (-5 / 3) / (0.423 * k * k * path_m)


def _turbulent(cn2, *extra):
    """Free space over 3 m (plane-wave Rytov variance 0.60 at D/r0 = 100: weak fluctuations,
    accepted), fiber coupling at beta = 1 of a specular return, Kolmogorov-like outer scale."""
    focal = 0.5 * np.pi * D_TEL_M * 4.6e-6 / WAVELENGTH_M
    return ("atm.state=on", "atm.Pattn=-30", "atm.dst=3", "system.reference_delay_s=0",
            "sys.f_highpass=2e4", f"atm.Cn2={cn2:.6g}", 'effects.enabled=["coupling","turbulence"]',
            "effects.coupling.obstruction_ratio=0", f"effects.coupling.focal_length_m={focal:.6g}",
            "effects.coupling.mode_field_radius_m=4.6e-6",
            "effects.coupling.fiber_numerical_aperture=0.14", 'effects.coupling.target="specular"',
            *extra, "effects.turbulence.outer_scale_m=1e4")


PTX_CH5 = _ptx_dbm()
FROZEN_16PX = ('effects.turbulence.fading="frozen_flow"', "effects.turbulence.transverse_speed_mps=10",
               "effects.turbulence.shot_interval_s=1e-3", "effects.turbulence.screen_pixels=16")


# ------------------------------------------------------------------ the catalogue's types

@dataclass(frozen=True)
class Expect:
    """The expected outcome of a case and where it comes from.

    ``outcome``: "valid" (no flag, every number finite), "flagged" (``flags`` all present, at
    least one of ``any_flag`` when given, ``null`` keys null), "refused" (``message`` found in
    the refusal) or "codes" (survey: ``required`` <= detected codes present <= ``allowed``).
    ``check(case, tier, outcome)`` -> problems: the case's own further checks."""

    outcome: str
    source: str
    flags: tuple = ()
    any_flag: tuple = ()
    null: tuple = ()
    message: str = ""
    required: frozenset = frozenset()
    allowed: frozenset = frozenset(range(6))
    check: Callable | None = None

    def describe(self) -> str:
        if self.outcome == "valid":
            return "valid: no flag, all finite"
        if self.outcome == "refused":
            return f"refused: /{self.message}/"
        if self.outcome == "codes":
            allowed = ", ".join(str(c) for c in sorted(self.allowed))
            text = f"`detected` codes within {{{allowed}}}"
            if self.required:
                text += ", " + " and ".join(str(c) for c in sorted(self.required)) + " present"
            return text
        parts = [f"`{f}`" for f in self.flags]
        if self.any_flag:
            parts.append("one of " + " / ".join(f"`{f}`" for f in self.any_flag))
        if not parts:
            parts.append("(any flag)")
        text = "flagged " + " + ".join(parts)
        return text + (f"; null: {_nulls(self.null)}" if self.null else "")


@dataclass(frozen=True)
class Case:
    """One hard case. ``kind``: "shot" (a lab-bench shot), "survey" (a small run) or "pointer"
    (run by the tests in ``pointers``). ``mission``: a path, or a builder ``(folder) -> path``
    described by ``built``. ``xfail``: tier -> the bug that (case, tier) exposes."""

    name: str
    what: str
    kind: str
    mission: object = None
    overrides: tuple = ()
    tiers: tuple = ()
    expect: Expect | None = None
    built: str = ""
    tier_overrides: dict = field(default_factory=dict)
    xfail: dict = field(default_factory=dict)
    pointers: tuple = ()


@dataclass
class Outcome:
    """What running a (case, tier) gave. ``kind``: "result", "refused", "error" or "skipped".
    ``record``: a shot's JSON object (nulls for non-finite) or a survey's dataset; ``cfg`` the
    configuration the shot ran with."""

    kind: str
    code: int | None = None
    message: str = ""
    record: object = None
    cfg: object = None


# ------------------------------------------------------------------ specific checks

def _true_range_in_bracket(case, tier, o):
    """Table 4.10: the true distance lies between d_lo and d_hi (the 3 dB range bracket) for a
    beat read at a high SNR."""
    r, dst = o.record, o.cfg.channel.distance_m
    if r["d_lo"] is None or r["d_hi"] is None or not r["d_lo"] <= dst <= r["d_hi"]:
        return [f"atm.dst = {dst:.6g} m outside [d_lo, d_hi] = [{r['d_lo']}, {r['d_hi']}]"]
    return []


def _below_threshold(case, tier, o):
    """SNR below the 10 dB detection threshold (a closed form or the largest noise peak)."""
    snr = o.record["SNR"]
    return [] if snr is not None and snr < DETECTION_THRESHOLD_DB else [
        f"SNR = {_g(snr)} dB, not below the {DETECTION_THRESHOLD_DB:g} dB threshold"]


def _psig_is(target_dbm):
    def check(case, tier, o):
        p = o.record["Psig"]
        return [] if p is not None and abs(p - target_dbm) < 1e-6 else [
            f"Psig = {_g(p)} dBm, expected {target_dbm:.6g} dBm (Ptx - atm.Pattn)"]
    return check


def _all(*checks):
    def check(case, tier, o):
        return [p for c in checks for p in c(case, tier, o)]
    return check


def _nothing_null(case, tier, o):
    missing = [k for k in SHOT_KEYS if o.record.get(k) is None]
    return [f"null without cause: {', '.join(missing)}"] if missing else []


def _beat_measured(case, tier, o):
    """The beat of the lag within the period is measured (only the range is ambiguous)."""
    return [] if o.record["f_beat_hz"] is not None else ["f_beat_hz null: the beat was not read"]


def _turbulent_loss(case, tier, o):
    """Mutual-coherence mean coupling (Kolmogorov, D_phi = 6.88 (d/r0)^(5/3)) against the
    same shot in clear air: the loss is -10 log10(<eta>(D/r0 = 100) / eta(beta = 1)), within
    3 % (the 1e4 m outer scale, tests/test_effects.py)."""
    from chirplidar.atmosphere import turbulent_coupling_exact
    from chirplidar.optics import coupling_efficiency

    clear = simulate_shot(load_mission(CH5, list(_turbulent(0.0, 'effects.turbulence.fading="mean"'))),
                          tier="link")["Psig"]
    expected = 10 * np.log10(turbulent_coupling_exact(100.0, 1.0, 0.0) / coupling_efficiency(1.0, 0.0))
    loss = o.record["Psig"] - clear
    if abs(loss - expected) > 10 * np.log10(1.03):
        return [f"turbulent loss {loss:.3f} dB, closed form {expected:.3f} dB"]
    return []


def _per_beam_codes(*codes):
    """Each beam's shots all carry its code."""
    def check(case, tier, o):
        det = o.record["detected"].values
        return [f"beam {b}: codes {sorted(set(det[b].tolist()))}, expected {{{c}}}"
                for b, c in enumerate(codes) if not np.all(det[b] == c)]
    return check


def _incidence_deg(*expected):
    """Each beam's incidence angle [deg] within 0.5 deg of its closed form."""
    def check(case, tier, o):
        inc = np.degrees(o.record["incidence_angle"].values)
        return [f"beam {b}: incidence {np.nanmin(inc[b]):.2f}-{np.nanmax(inc[b]):.2f} deg, "
                f"expected {e:g}" for b, e in enumerate(expected)
                if not np.all(np.abs(inc[b] - e) < 0.5)]
    return check


def _detected_ranges_within(limit_m):
    """Issue 14's acceptance: no detected shot's range off by more than ``limit_m``."""
    def check(case, tier, o):
        ds = o.record
        err = ds["range_error"].values[ds["detected"].values == 1]
        return [f"detected range error up to {np.max(np.abs(err)):.3g} m"] if (
            err.size and np.max(np.abs(err)) > limit_m) else []
    return check


# The DEM of the no-data case: 40 x 40 pixels of 50 m (EPSG:3413), a 10 x 10 pixel no-data block
# in its middle. In "holes" mode every cell touching a no-data pixel is left out
# (tests/test_scene.py): cells from pixel centre 14 to pixel centre 25, x within
# (-275, +275) m of the DEM's centre.
DEM_WEST, DEM_NORTH, DEM_RES, DEM_N, DEM_HOLE = -200000.0, -2500000.0, 50.0, 40, (15, 25)
HOLE_HALF_M = (DEM_HOLE[1] - DEM_HOLE[0] + 1) * DEM_RES / 2


def _hole_is_no_surface(case, tier, o):
    """Nadir shots over the hole (20 m inside its edge) have no surface (2); shots 20 m outside
    it have one (1)."""
    ds = o.record
    cx = DEM_WEST + DEM_N * DEM_RES / 2
    dx = np.abs(ds["platform_x"].values[0] - cx)
    det = ds["detected"].values[0]
    out = []
    if not np.all(det[dx < HOLE_HALF_M - 20] == 2):
        out.append("a shot over the hole is not code 2")
    if not np.all(det[dx > HOLE_HALF_M + 20] == 1):
        out.append("a shot beside the hole is not code 1")
    return out


def _some_detected(case, tier, o):
    return [] if np.any(o.record["detected"].values == 1) else ["no shot detected"]


# ------------------------------------------------------------------ survey builders

def _miss(tmp):
    # Beam 1 looks 55 deg off nadir towards +x from 2.5 km: it meets the ground 3.6 km ahead,
    # beyond the 4 km scene's edge (tests/test_output_flags.py).
    return write_flat_uav_mission(tmp, "miss", altitude_m=2500.0, prf=20.0, stop=0.5, subrays=3,
                                  beams='pattern = "custom"\noff_nadir_deg = [0.0, 55.0]\n'
                                        'azimuth_deg = [90.0, 90.0]')


def _water(tmp):
    scene = write_scene(tmp, "water", 'flat height_m = 0.0\nmaterial = "open_water"',
                        stem="water_scene")
    scene.write_text(scene.read_text() + "[materials.open_water]\nwind_speed_mps = 3.0\n")
    return write_uav_mission(tmp, scene, "water", altitude=200.0, stop="0.5", subrays=3,
                             beams='pattern = "custom"\noff_nadir_deg = [0.0, 55.0]\n'
                                   'azimuth_deg = [90.0, 90.0]')


def _grazing(tmp):
    scene = write_scene(tmp, "slope", 'sloped slope_deg = 40.0\nazimuth_deg = 270.0\n'
                        'height_m = 100.0\nmaterial = "snow"', stem="slope_scene")
    return write_uav_mission(tmp, scene, "grazing", altitude=400.0, stop="0.5", subrays=3,
                             waypoints="[[-100.0, 0.0], [100.0, 0.0]]",
                             beams='pattern = "custom"\noff_nadir_deg = [0.0, 45.0]\n'
                                   'azimuth_deg = [0.0, 0.0]')


def _dem_holes(tmp):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = np.full((DEM_N, DEM_N), 100.0, np.float32)
    z[DEM_HOLE[0]:DEM_HOLE[1], DEM_HOLE[0]:DEM_HOLE[1]] = -9999.0
    (tmp / "dem").mkdir(exist_ok=True)
    with rasterio.open(tmp / "dem" / "holes.tif", "w", driver="GTiff", height=DEM_N, width=DEM_N,
                       count=1, dtype="float32", crs="EPSG:3413", nodata=-9999.0,
                       transform=Affine(DEM_RES, 0.0, DEM_WEST, 0.0, -DEM_RES, DEM_NORTH)) as dst:
        dst.write(z, 1)
    scene = tmp / "dem_scene.toml"
    scene.write_text('name = "dem holes"\nepsg = 3413\neffects = []\n[terrain]\nsource = "dem"\n'
                     '[terrain.dem]\npath = "dem/holes.tif"\nmaterial = "snow"\nnodata = "holes"\n'
                     '[atmosphere]\ncn2_profile = "none"\nextinction_per_m = 0.0\n'
                     'scale_height_m = 1200.0\n')
    return write_uav_mission(tmp, scene, "dem", altitude=600.0, beams='pattern = "nadir"',
                             waypoints="[[-600.0, 0.0], [600.0, 0.0]]", stop="60.0", subrays=3,
                             prf=1.0)


def _mesh_scene(tmp, name, mesh_file):
    scene = tmp / f"{name}_scene.toml"
    scene.write_text(f'name = "{name}"\nepsg = 3413\neffects = []\n[terrain]\nsource = "mesh"\n'
                     'center_lat_deg = 69.0\ncenter_lon_deg = -49.0\n[terrain.mesh]\n'
                     f'path = "{mesh_file}"\nmaterial = "snow"\ncoordinates = "scene_centre"\n'
                     '[atmosphere]\ncn2_profile = "none"\nextinction_per_m = 0.0\n'
                     'scale_height_m = 1200.0\n')
    return write_uav_mission(tmp, scene, name, altitude=600.0, beams='pattern = "nadir"',
                             waypoints="[[-10.0, 0.0], [30.0, 0.0]]", stop="2.0", subrays=7,
                             prf=10.0)


def _degenerate_mesh(tmp):
    # A 4 km x 4 km x 10 m box (top at z = 5 m) plus a zero-area (collinear) face on its top.
    (tmp / "meshes").mkdir(exist_ok=True)
    v = ("-2000 -2000 -5", "2000 -2000 -5", "2000 2000 -5", "-2000 2000 -5",
         "-2000 -2000 5", "2000 -2000 5", "2000 2000 5", "-2000 2000 5",
         "0 0 5", "10 0 5", "20 0 5")
    f = ("1 3 2", "1 4 3", "5 6 7", "5 7 8", "1 2 6", "1 6 5", "2 3 7", "2 7 6", "3 4 8",
         "3 8 7", "4 1 5", "4 5 8", "9 10 11")
    (tmp / "meshes" / "degenerate.obj").write_text(
        "".join(f"v {p}\n" for p in v) + "".join(f"f {q}\n" for q in f))
    return _mesh_scene(tmp, "degenerate", "meshes/degenerate.obj")


def _empty_mesh(tmp):
    (tmp / "meshes").mkdir(exist_ok=True)
    (tmp / "meshes" / "empty.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")  # no faces
    return _mesh_scene(tmp, "empty", "meshes/empty.obj")


def _zero_shots(tmp):
    return write_flat_uav_mission(tmp, "zero", altitude_m=1000.0, prf=20.0, stop=0.0, subrays=3,
                                  beams='pattern = "nadir"')


# ------------------------------------------------------------------ the catalogue

_NEXT_CHIRP_LAG_S = 80e-6
CASES: tuple[Case, ...] = (
    # -------------------------------------------------------------- lab-bench shots
    Case("satellite_range",
         "550 km one way (a 3.7 ms round trip, 57 periods of the 64 us chirp); the reference "
         "delay (sys.fmaxopt) takes the bulk",
         "shot", BENCH, ("atm.dst=550e3", "channel.group_index=1.0", "sys.fmaxopt=20e6",
                         "atm.Pattn=40"), TIERS,
         Expect("valid", "Table 4.10: atm.dst within [d_lo, d_hi]", check=_true_range_in_bracket)),
    Case("weak_signal_strong_lo",
         "-110 dBm received against a 10 mW LO: below the -96 dBm sensitivity of Table 5.4",
         "shot", CH5, ("COH.P_LO=10e-3", f"atm.Pattn={PTX_CH5 + 110:.6f}"), TIERS,
         Expect("valid", "Psig = Ptx - atm.Pattn = -110 dBm; SNR < 10 dB: the shot-noise limit "
                "eta P / (h nu RBW) (eq. 2.6.2) is 3.0 dB, the time-domain tiers read the largest "
                "noise peak (docs: explanation/validation/crossval.md)",
                check=_all(_psig_is(-110.0), _below_threshold))),
    Case("far_below_noise_floor",
         "atm.Pattn = 250 dB: -262 dBm received, 170 dB below the noise floor",
         "shot", CH5, ("atm.Pattn=250",), TIERS,
         Expect("valid", "Psig = Ptx - atm.Pattn; SNR < 10 dB (eq. 2.6.2); the beat inside the "
                "processed band (the invariant)",
                check=_all(_psig_is(PTX_CH5 - 250), _below_threshold))),
    Case("zero_return",
         "atm.Pattn = inf: no signal at all",
         "shot", CH5, ("atm.Pattn=inf",), TIERS,
         Expect("flagged", "flag no_return (tiers.common.detection_flags: zero received power)",
                flags=("no_return",), null=(*BEAT, "Psig", "Crx", "SNR"))),
    Case("no_lo",
         "COH.P_LO = 0: a coherent receiver with nothing to beat with",
         "shot", CH5, ("COH.P_LO=0",), TIERS,
         Expect("flagged", "flag no_lo (tiers.common.detection_flags)", flags=("no_lo",),
                null=(*BEAT, "Crx", "SNR"))),
    Case("modulator_at_null_no_drive",
         "chrp.Vpp = 0 with the bench's bias at the modulator's null (V_b = V_pi): no light "
         "leaves the modulator, no LO, no carrier",
         "shot", CH5, ("chrp.Vpp=0",), TIERS,
         Expect("flagged", "cos^2(pi V_pi / 2 V_pi) = 0: zero transmitted and received power "
                "(flag no_return's definition); no drive (flag no_chirp)",
                flags=("no_return", "no_chirp"), null=(*BEAT, "Ptx", "Psig", "Crx", "SNR"))),
    Case("modulator_bias_tiny",
         "modulator.bias_v tiny (mzm.Vdc = 1e-9 V, V_pi = 2 V): the field's fundamental "
         "2 sin(pi V_b / 2 V_pi) J1 vanishes, so no beat at f_R",
         "shot", CH5, ("mzm.Vdc=1e-9",), TIERS,
         Expect("flagged", "Jacobi-Anger (transmitter.mzm.mzm_harmonic_dominates): the field's "
                "2 cos(alpha) J2 outweighs 2 sin(alpha) J1, the strongest beat is 2 f_R: flag "
                "harmonic_beat, beat and range null", flags=("harmonic_beat",), null=BEAT)),
    Case("doppler_beyond_beat",
         "20 m/s closing: f_d = 2 v / lambda = 30.5 MHz above the 22 MHz beat (sign ambiguity)",
         "shot", CH5, ("atm.Pattn=60", 'effects.enabled=["doppler"]',
                       "effects.doppler.radial_velocity_mps=20"), TIERS,
         Expect("flagged", "Appendix D: f_d > f_R folds the lower line through zero; flag "
                "doppler_ambiguous", flags=("doppler_ambiguous",))),
    Case("chirp_beyond_nyquist",
         "chrp.F2 = 2 GHz at sims.Fs = 3 GS/s: the chirp cannot be sampled",
         "shot", CH5, ("chrp.F2=2e9",), TIERS,
         Expect("refused", "sampling theorem: F2 + F0 < Fs / 2",
                message=r"chrp\.F2 \+ chrp\.F0 = 2e\+09 Hz\) is at or above the Nyquist frequency")),
    Case("beat_above_nyquist",
         "sims.Fs = 800 MS/s and a lag of 90 us of the 106 us period: kappa x lag = 450 MHz "
         "above the 400 MHz Nyquist frequency",
         "shot", CH5, ("sims.Fs=800e6", f"atm.dst={_dst_at_lag(90e-6):.4f}"), TIERS,
         Expect("flagged", "flag beat_above_nyquist (tiers.common.detection_flags); the beat "
                "is not read", flags=("beat_above_nyquist",), null=BEAT)),
    Case("return_overlaps_next_chirp",
         "a lag of 80 us of the 106 us period (19.1 km): the return's 40 us ramp overlaps the "
         "next reference ramp by 14 us, the tone is kappa (T - lag) = 130 MHz, the beat of a "
         "lag of -26 us",
         "shot", CH5, (f"atm.dst={_dst_at_lag(_NEXT_CHIRP_LAG_S):.4f}",), TIERS,
         Expect("flagged", "waveform.chirp (a ramp of 40 us, no amplitude on the falling ramp): "
                "the only tone is that of lag - T < 0, so the range is ambiguous by a period "
                "(flag range_ambiguous's definition) or the beat out of the band: range null",
                any_flag=("range_ambiguous", "beat_out_of_band", "no_overlap"), null=RANGE,
                flags=("next_chirp_tone",))),
    Case("ambiguous_by_a_period",
         "atm.dst one chirp period (c T / 2 n = 10.9 km) beyond the bench's: the same beat",
         "shot", CH5, (f"atm.dst={load_mission(CH5).channel.distance_m + _period_m():.4f}",), TIERS,
         Expect("flagged", "flag range_ambiguous: the delay minus the reference is T or more; "
                "the beat of the lag within the period is measured", flags=("range_ambiguous",),
                null=RANGE, check=_beat_measured)),
    Case("saturating_signal",
         "atm.Pattn = -20 dB: +8 dBm received, the balanced pair's amplifier saturates",
         "shot", CH5, ("atm.Pattn=-20",), TIERS,
         Expect("flagged", "flag saturation: differential peak 2 T_c sqrt(P_lo P_sig) above "
                "balanced.saturation_power_w (tests/test_output_flags.py); the numbers stand",
                flags=("saturation",), check=_nothing_null)),
    Case("zero_linewidth",
         "lsr.Lw = 0: a perfectly coherent laser",
         "shot", CH5, ("lsr.Lw=0",), TIERS,
         Expect("valid", "Table 4.10: atm.dst within [d_lo, d_hi]", check=_true_range_in_bracket)),
    Case("zero_linewidth_phase_noise",
         "phase_noise enabled with lsr.Lw = 0: an effect with nothing to simulate",
         "shot", CH5, ("lsr.Lw=0", 'effects.enabled=["phase_noise"]'), TIERS,
         Expect("refused", "effects.enabled is the one switch of each effect (docs: explanation/physics.md)",
                message=r"'phase_noise' needs a linewidth > 0")),
    Case("very_large_linewidth",
         "lsr.Lw = 1 GHz: 2 pi dnu x lag = 2.8e4, the beat's Lorentzian (FWHM 2 dnu = 2 GHz) "
         "fills the band",
         "shot", CH5, ("lsr.Lw=1e9", 'effects.enabled=["phase_noise"]'), ("baseband", "rf"),
         Expect("valid", "delayed self-homodyne spectrum: a Lorentzian of FWHM 2 dnu, no line "
                "above its own pedestal, so SNR < 10 dB, as the rf tier (the reference) reads it",
                check=_below_threshold)),
    Case("very_large_linewidth_link",
         "lsr.Lw = 1 GHz in the link tier, whose closed form leaves out the phase-noise pedestal",
         "shot", CH5, ("lsr.Lw=1e9", 'effects.enabled=["phase_noise"]'), ("link",),
         Expect("flagged", "flag linewidth_beyond_link_tier (tiers.link.LINK_MAX_LINEWIDTH_HZ: "
                "the coherence factor is checked against rf to 20 kHz, tests/test_validation.py)",
                flags=("linewidth_beyond_link_tier",))),
    Case("r0_far_below_aperture",
         "atm.Cn2 giving D / r0 = 100 (r0 = 2 mm under the 203 mm telescope) over 3 m",
         "shot", CH5, _turbulent(_cn2_for(100.0, 3.0), 'effects.turbulence.fading="mean"'), TIERS,
         Expect("valid", "mutual-coherence mean coupling at D/r0 = 100 (-39.67 dB relative to "
                "clear air; Kolmogorov, tests/test_atmosphere.py) within 3 %",
                check=_all(_turbulent_loss, _true_range_in_bracket))),
    Case("r0_below_screen_step",
         "frozen-flow screen of 16 pixels across the aperture at D / r0 = 100: a pixel of "
         "12.7 mm against r0 = 2 mm",
         "shot", CH5, _turbulent(_cn2_for(100.0, 3.0), *FROZEN_16PX), TIERS,
         Expect("refused", "a screen must sample r0 (models.TurbulenceEffect.screen_pixels: the "
                "pixel D / screen_pixels must not exceed r0)", message=r"coarser than r0")),
    # -------------------------------------------------------------- surveys
    Case("beam_misses_terrain",
         "a UAV 2.5 km up, beam 1 at 55 deg off nadir meets the ground beyond the scene's edge",
         "survey", _miss, LOUD, ("link",),
         Expect("codes", "code 2 (no surface in beam) on beam 1, 1 on the nadir beam",
                required=frozenset({1, 2}), allowed=frozenset({1, 2}),
                check=_per_beam_codes(1, 2)),
         built="flat snow, UAV at 2500 m, beams 0 and 55 deg"),
    Case("open_water_grazing",
         "open water (3 m/s wind) seen 55 deg off nadir: Cox-Munk backscatter "
         "~ exp(-tan^2 / mss) = 1e-48 of nadir's",
         "survey", _water, (), TIERS,
         Expect("codes", "Cox-Munk (mss = 0.0184): beam 1 below threshold (0), the nadir beam "
                "detected (1)", required=frozenset({0, 1}), allowed=frozenset({0, 1}),
                check=_all(_per_beam_codes(1, 0), _incidence_deg(0.0, 55.0))),
         built="flat open water, UAV at 200 m, beams 0 and 55 deg",
         tier_overrides={"baseband": ("processing.averages=2",),
                         "rf": ("processing.averages=2", "survey.stop_s=0.1")}),
    Case("grazing_incidence",
         "beam 1 at 45 deg forward over a 40 deg slope falling away: 85 deg incidence",
         "survey", _grazing, LOUD, TIERS,
         Expect("codes", "incidence = 40 deg (nadir on the slope) and 45 + 40 = 85 deg "
                "(closed forms); 30 dB more power: both detected",
                required=frozenset({1}), allowed=frozenset({1}),
                check=_incidence_deg(40.0, 85.0)),
         built="snow slope of 40 deg, UAV at 400 m, beams 0 and 45 deg forward",
         tier_overrides={"baseband": ("processing.averages=2",),
                         "rf": ("processing.averages=2", "survey.stop_s=0.1")}),
    Case("dem_nodata_holes",
         "a DEM with a 500 m no-data block under the track (nodata = \"holes\")",
         "survey", _dem_holes, LOUD, ("link",),
         Expect("codes", "test_scene's holes rule (cells touching a no-data pixel are left out): "
                "code 2 over the hole, 1 beside it", required=frozenset({1, 2}),
                allowed=frozenset({1, 2}), check=_hole_is_no_surface),
         built="GeoTIFF 2 km square, 10 x 10 no-data pixels, nadir UAV at 600 m"),
    Case("degenerate_mesh_faces",
         "a mesh terrain with a zero-area face among its good ones",
         "survey", _degenerate_mesh, LOUD, ("link",),
         Expect("codes", "the zero-area face is never hit: every shot detected on the box top",
                required=frozenset({1}), allowed=frozenset({1})),
         built="OBJ box 4 km wide + one collinear face, nadir UAV at 600 m"),
    Case("empty_mesh",
         "a mesh file with vertices and no face",
         "survey", _empty_mesh, (), ("link",),
         Expect("refused", "nothing to cast rays on", message=r"has no faces"),
         built="OBJ with 3 vertices, 0 faces"),
    Case("zero_shots",
         "survey.stop_s = survey.start_s: a trajectory with no shot",
         "survey", _zero_shots, (), ("link",),
         Expect("refused", "an empty span has nothing to simulate", message=r"holds no shot"),
         built="flat snow, UAV, span 0..0 s"),
    Case("range_window",
         "icesat_like with a 300 m range window over ~1.4 km of relief",
         "survey", ICESAT, ("survey.start_s=-0.02", "survey.stop_s=0.02",
                            "survey.range_window_m=300"), ("link",),
         Expect("codes", "returns beyond the window are code 3, never a wrong detected range "
                "(issue 14: |range error| < 10 m)", required=frozenset({1, 3}),
                allowed=frozenset({0, 1, 2, 3, 4}), check=_detected_ranges_within(10.0))),
    Case("satellite_600km",
         "icesat_like at 600 km (4 ms delays), range gate and pointing untouched",
         "survey", ICESAT, ("platform.orbit.altitude_m=600e3",), TIERS,
         Expect("codes", "issue 14: detections with |range error| < 10 m, codes 0-4 only",
                required=frozenset({1}), allowed=frozenset({0, 1, 2, 3, 4}),
                check=_detected_ranges_within(10.0)),
         tier_overrides={"link": ("survey.start_s=-0.02", "survey.stop_s=0.02"),
                         "baseband": ("survey.start_s=-0.0005", "survey.stop_s=0.0005"),
                         "rf": ("survey.start_s=-0.0001", "survey.stop_s=0.0001")}),
    Case("any_pass_ascending_700km",
         "icesat_like flown ascending at 700 km, range gate and pointing untouched",
         "survey", ICESAT, ("survey.start_s=-0.02", "survey.stop_s=0.02",
                            "platform.orbit.pass_direction=ascending",
                            "platform.orbit.altitude_m=700e3"), ("link",),
         Expect("codes", "issue 14: detections with |range error| < 10 m, codes 0-4 only",
                required=frozenset({1}), allowed=frozenset({0, 1, 2, 3, 4}),
                check=_detected_ranges_within(10.0))),
    # -------------------------------------------------------------- run by other modules
    Case("any_pass_direction_and_height",
         "icesat_like ascending and descending at 450, 500 and 700 km, 20 000 shots each",
         "pointer", pointers=("tests/test_range_gate.py::test_any_pass_keeps_its_ranges",
                              "tests/test_range_gate.py::test_ascending_detects_like_descending")),
    Case("survey_range_ambiguous",
         "a UAV survey whose returns arrive before the reference delay (code 5)",
         "pointer", pointers=(("tests/test_output_flags.py::"
                              "test_survey_return_before_the_reference_is_range_ambiguous"),)),
    Case("strong_turbulence",
         "r0 far below the aperture over the 1572 m bench: Rytov variance 5.5e3",
         "pointer", pointers=(("tests/test_bad_input.py::test_catalogued_bad_input"
                              "[rytov_variance_above_1]"),
                              "tests/test_atmosphere.py::test_coupling_hard_case_d_over_r0_100",
                              "tests/test_atmosphere.py::test_r0_far_below_grid_step_is_refused")),
    Case("mesh_and_dem_files",
         "empty, point-only and degenerate-only meshes; DEM no-data as error, holes or fill",
         "pointer", pointers=("tests/test_scene.py::test_mesh_without_faces",
                              "tests/test_terrain.py::test_from_mesh_file_degenerate_only_names_file",
                              "tests/test_scene.py::test_dem_nodata_error_by_default",
                              "tests/test_scene.py::test_dem_nodata_holes_and_fill")),
    Case("nan_inf_in_any_input",
         "NaN, inf, wrong types, missing and unknown keys, truncated and binary files",
         "pointer", pointers=(("tests/test_bad_input.py::"
                              "test_mutated_missions_and_scenes_are_refused_in_one_line_or_run"),
                              "tests/test_bad_input.py::test_catalogued_bad_input")),
    Case("damaged_chunk_files",
         "a chunk inverted, truncated or unsealed; damaged after its seal",
         "pointer", pointers=(
             "tests/test_run_scale.py::test_resume_recomputes_bad_chunks_and_merges_none[inverted]",
             "tests/test_run_scale.py::test_resume_recomputes_bad_chunks_and_merges_none[truncated]",
             "tests/test_run_scale.py::test_resume_recomputes_bad_chunks_and_merges_none[unsealed]",
             "tests/test_run_scale.py::test_a_chunk_damaged_after_its_seal_is_never_merged")),
    Case("foreign_chunk_files",
         "a chunk of another run (another seed), two chunks swapped",
         "pointer", pointers=(
             "tests/test_run_scale.py::test_resume_recomputes_bad_chunks_and_merges_none[foreign]",
             "tests/test_run_scale.py::test_resume_recomputes_bad_chunks_and_merges_none[swapped]")),
    Case("two_runs_one_output",
         "a second run on an output another run is writing; the lock of a killed run",
         "pointer", pointers=("tests/test_run_scale.py::test_one_run_per_output",)),
    Case("full_disk",
         "no space left while writing the lock, manifest, a chunk or the merge",
         "pointer", pointers=("tests/test_faults.py::test_disk_full_is_one_line_and_resume_is_exact",
                              "tests/test_faults.py::test_real_full_disk",
                              "tests/test_faults.py::test_real_full_disk_with_workers")),
    Case("cluster_without_workers",
         "a Dask scheduler no worker ever joins",
         "pointer", pointers=(("tests/test_run_scale.py::"
                              "test_scheduler_without_workers_times_out_with_a_message"),)),
)
BY_NAME = {c.name: c for c in CASES}


# ------------------------------------------------------------------ running a case

def _cli(argv: list[str], cache: Path) -> tuple[int | None, str, BaseException | None]:
    """``chirplidar argv`` in this process: (exit code, stderr, exception raised out of it)."""
    out, err = io.StringIO(), io.StringIO()
    with mock.patch.dict(os.environ, {"CHIRPLIDAR_CACHE": str(cache)}), \
            contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            return main(argv), err.getvalue(), None
        except Exception as exc:   # noqa: BLE001 - a traceback the command line let through
            return None, err.getvalue(), exc


def _refusal(code, stderr, command) -> Outcome:
    lines = [ln for ln in stderr.splitlines() if ln.strip() and ": warning: " not in ln]
    if code == 2 and len(lines) == 1 and lines[0].startswith(f"chirplidar {command}: "):
        return Outcome("refused", code, lines[0][len(f"chirplidar {command}: "):])
    return Outcome("error", code, f"exit {code}: " + " | ".join(lines))


def _json_value(v):
    return float(v) if v is not None and math.isfinite(float(v)) else None


def _run_shot(case: Case, tier: str) -> Outcome:
    over = [*case.overrides, *case.tier_overrides.get(tier, ())]
    try:
        cfg = load_mission(case.mission, over)
    except ValueError:
        cfg = None
    if tier == "baseband":   # the command line's shot offers link and rf
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)   # saturation
                r = simulate_shot(load_mission(case.mission, over), tier=tier)
        except ValueError as exc:    # ConfigError is a ValueError
            return Outcome("refused", None, str(exc))
        except Exception as exc:   # noqa: BLE001 - recorded as the outcome: a traceback
            return Outcome("error", None, f"{type(exc).__name__}: {exc}")
        rec = {k: _json_value(r[k]) for k in SHOT_KEYS}
        rec["flags"] = list(r["flags"])
        return Outcome("result", None, record=rec, cfg=cfg)
    argv = ["shot", str(case.mission), "--tier", tier, "--json"] + (["--set", *over] if over else [])
    out = io.StringIO()
    err = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except Exception as exc:   # noqa: BLE001 - recorded as the outcome: a traceback
            return Outcome("error", None, f"traceback: {type(exc).__name__}: {exc}")
    if code != 0:
        return _refusal(code, err.getvalue(), "shot")
    return Outcome("result", 0, record=json.loads(out.getvalue()), cfg=cfg)


def _run_survey(case: Case, tier: str, mission: Path, work: Path) -> Outcome:
    out = work / f"{case.name}_{tier}.nc"
    over = [*case.overrides, *case.tier_overrides.get(tier, ())]
    argv = ["run", str(mission), "--tier", tier, "--out", str(out), "--overwrite",
            "--no-progress"] + (["--set", *over] if over else [])
    code, err, exc = _cli(argv, work / "cache")
    if exc is not None:
        return Outcome("error", None, f"traceback: {type(exc).__name__}: {exc}")
    if code != 0:
        return _refusal(code, err, "run")
    return Outcome("result", 0, record=read_netcdf(out))


_OUTCOMES: dict[tuple[str, str], Outcome] = {}
_BUILT: dict[str, Path] = {}


def outcome(case: Case, tier: str, work: Path) -> Outcome:
    """Run (case, tier) once per session (the docs test reuses the parametrized tests' runs)."""
    key = (case.name, tier)
    if key not in _OUTCOMES:
        if case.kind == "shot":
            _OUTCOMES[key] = _run_shot(case, tier)
        else:
            mission = case.mission
            if callable(mission):
                if case.name not in _BUILT:
                    folder = work / case.name
                    folder.mkdir(parents=True, exist_ok=True)
                    _BUILT[case.name] = mission(folder)
                mission = _BUILT[case.name]
            _OUTCOMES[key] = _run_survey(case, tier, mission, work)
    return _OUTCOMES[key]


# ------------------------------------------------------------------ the invariant and the verdict

def _g(v):
    return "null" if v is None else f"{v:.3g}"


def shot_invariant(rec: dict, cfg) -> list[str]:
    """Every Table 4.10 number finite, or null with a flag whose definition nulls it; no
    sentinel; a beat inside [highpass, top of the peak search] unless flagged out of band."""
    flags = rec["flags"]
    problems = []
    for key in SHOT_KEYS:
        v = rec.get(key)
        if v is None:
            if not any(key in EXPLAINS.get(f, ()) for f in flags):
                problems.append(f"{key} null with no flag that explains it (flags {flags})")
        elif v in SENTINELS:
            problems.append(f"{key} = {v:g}: a sentinel value")
    fb = rec.get("f_beat_hz")
    if fb is not None and cfg is not None and not {"beat_out_of_band", "beat_above_nyquist"} & set(flags):
        lo = cfg.processing.highpass_hz
        hi = cfg.processing.peak_search_max_hz or cfg.simulation.sample_rate_hz / 2
        if not lo <= fb <= hi:
            problems.append(f"f_beat_hz = {fb:.3g} Hz outside the processed band "
                            f"[{lo:.3g}, {hi:.3g}] Hz with no beat_out_of_band flag")
    return problems


def survey_invariant(ds) -> list[str]:
    """Per-shot variables: finite where detected == 1; NaN only where detected != 1 (and never
    in a variable the schema says is always there); never inf or a sentinel; codes 0-5."""
    det = ds["detected"].values
    problems = []
    if not set(np.unique(det).tolist()) <= set(CODE_NAMES):
        problems.append(f"detected codes {sorted(set(np.unique(det).tolist()))} outside 0-5")
    kind = "pulsed" if ds.attrs.get("tier") == "pulsed" else "chirped"
    for name in sorted(ds.variables):
        a = ds[name].values
        if a.dtype.kind != "f" or a.shape != det.shape:
            continue
        bad = ~np.isfinite(a)
        if name in NOT_MEASURED_BY[kind]:   # fill values throughout: not this kind's measurement
            if not np.all(bad):
                problems.append(f"{name}: measured by a {kind} instrument")
            continue
        spec = SCHEMA_BY_NAME.get(name)
        if np.any(np.isinf(a)):
            problems.append(f"{name}: {int(np.isinf(a).sum())} inf")
        if np.any(bad & (det == 1)):
            problems.append(f"{name}: {int(np.sum(bad & (det == 1)))} non-finite on detected shots")
        if spec is not None and not spec.nan_allowed and np.any(bad):
            problems.append(f"{name}: NaN in a variable that is always there")
        if np.any(np.isin(a[~bad], SENTINELS)):
            problems.append(f"{name}: a sentinel value")
    return problems


def verdict(case: Case, tier: str, o: Outcome) -> list[str]:
    """The problems of an outcome: the invariant's, then the case's expected outcome's."""
    e = case.expect
    if o.kind == "skipped":
        return []
    if o.kind == "error":
        return [o.message]
    if e.outcome == "refused":
        if o.kind != "refused":
            return [f"ran where a refusal /{e.message}/ was expected"]
        return [] if re.search(e.message, o.message) else [f"refusal {o.message!r} lacks /{e.message}/"]
    if o.kind == "refused":
        return [f"refused: {o.message}"]
    if case.kind == "survey":
        problems = survey_invariant(o.record)
        present = set(np.unique(o.record["detected"].values).tolist())
        if not e.required <= present <= e.allowed:
            problems.append(f"detected codes {sorted(present)}: expected a subset of "
                            f"{sorted(e.allowed)} holding {sorted(e.required)}")
    else:
        rec = o.record
        problems = shot_invariant(rec, o.cfg)
        flags = rec["flags"]
        if e.outcome == "valid" and flags:
            problems.append(f"flags {flags} on a valid case")
        missing = [f for f in e.flags if f not in flags]
        if missing:
            problems.append(f"flags {flags}: {', '.join(missing)} missing")
        if e.outcome == "flagged" and not flags:
            problems.append("no flag")
        if e.any_flag and not set(e.any_flag) & set(flags):
            problems.append(f"flags {flags}: none of {', '.join(e.any_flag)}")
        not_null = [k for k in e.null if rec.get(k) is not None]
        if not_null:
            problems.append("not null: " + ", ".join(f"{k} = {_g(rec[k])}" for k in not_null))
    if e.check is not None and not problems:
        problems += e.check(case, tier, o)
    return problems


# ------------------------------------------------------------------ the tests

def _params():
    out = []
    for case in CASES:
        for tier in case.tiers:
            marks = [pytest.mark.xfail(strict=True, reason=case.xfail[tier])] if tier in case.xfail else []
            out.append(pytest.param(case.name, tier, id=f"{case.name}-{tier}", marks=marks))
    return out


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("hard_cases")


@pytest.mark.parametrize(("name", "tier"), _params())
def test_hard_case(name, tier, work):
    case = BY_NAME[name]
    o = outcome(case, tier, work)
    if o.kind == "skipped":
        pytest.skip(o.message)
    problems = verdict(case, tier, o)
    assert not problems, f"{name} [{tier}]: " + "; ".join(problems)


def _pointer_target(pointer: str):
    """(file, function, parameter id or None) of ``tests/x.py::test_y[id]``."""
    m = re.fullmatch(r"(tests/[\w./]+\.py)::(\w+)(?:\[(.+)\])?", pointer)
    assert m, f"not a test id: {pointer}"
    return ROOT / m.group(1), m.group(2), m.group(3)


@pytest.mark.parametrize("name", [c.name for c in CASES if c.kind == "pointer"])
def test_pointers_exist(name):
    """Each pointed-to test is a module-level test function of its file; a parameter id is one
    of the strings its parametrize decorators list."""
    case = BY_NAME[name]
    assert case.pointers and not case.tiers
    for pointer in case.pointers:
        path, func, param = _pointer_target(pointer)
        assert path.is_file(), pointer
        tree = ast.parse(path.read_text())
        defs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert func in defs, f"{pointer}: no test {func} in {path.name}"
        if param is not None:
            decorators = defs[func].decorator_list
            consts = {n.value for d in decorators for n in ast.walk(d)
                      if isinstance(n, ast.Constant) and isinstance(n.value, str)}
            # parameters listed in a module-level table the decorator names (its keys/items)
            names = {n.id for d in decorators for n in ast.walk(d) if isinstance(n, ast.Name)}
            for node in tree.body:
                targets = (node.targets if isinstance(node, ast.Assign) else
                           [node.target] if isinstance(node, ast.AnnAssign) else [])
                if any(isinstance(t, ast.Name) and t.id in names for t in targets):
                    v = node.value
                    items = v.keys if isinstance(v, ast.Dict) else getattr(v, "elts", [])
                    consts |= {k.value for k in items if isinstance(k, ast.Constant)}
            assert param in consts, f"{pointer}: {param!r} is not one of its parameters"


def test_catalogue_is_well_formed():
    """Every runnable case names its tiers, its expectation and its source; xfail only on its
    own tiers; case names unique; the DESIGN list's items all present."""
    assert len(BY_NAME) == len(CASES)
    for c in CASES:
        if c.kind == "pointer":
            continue
        assert c.tiers and set(c.tiers) <= set(TIERS) and c.expect and c.expect.source, c.name
        assert set(c.xfail) <= set(c.tiers) and set(c.tier_overrides) <= set(c.tiers), c.name
        assert c.kind == "shot" or c.expect.outcome in ("codes", "refused"), c.name
    design = ("satellite", "noise_floor", "zero_return", "grazing", "r0", "doppler",
              "chirp_beyond_nyquist", "linewidth", "mesh", "dem", "zero_shots", "no_lo",
              "saturat", "range_window", "ambiguous", "any_pass", "nan_inf", "chunk",
              "two_runs", "full_disk", "workers", "beat_above_nyquist", "bias", "misses")
    for word in design:
        assert any(word in c.name for c in CASES), word


# ------------------------------------------------------------------ the docs table

def _nulls(keys) -> str:
    keys = list(keys)
    parts = []
    if all(k in keys for k in BEAT):
        parts.append("beat & range")
        keys = [k for k in keys if k not in BEAT]
    elif all(k in keys for k in RANGE):
        parts.append("range")
        keys = [k for k in keys if k not in RANGE]
    return ", ".join(parts + keys)


def _clean(text: str, work: Path) -> str:
    text = text.replace(str(work) + os.sep, "").replace(str(work), "<tmp>")
    text = text.replace(str(ROOT) + os.sep, "").replace("|", "\\|")
    return text


def summarize(case: Case, tier: str, o: Outcome, work: Path) -> str:
    """What a (case, tier) gave, in words (no timings, no paths)."""
    if o.kind == "skipped":
        return f"skipped ({o.message})"
    if o.kind == "error":
        return "error: " + _clean(o.message, work)[:120]
    if o.kind == "refused":
        m = re.search(case.expect.message, o.message) if case.expect.message else None
        where = "exit 2" if o.code == 2 else "ValueError"
        return f"refused ({where}): “{_clean(m.group(0) if m else o.message[:100], work)}”"
    if case.kind == "survey":
        codes = sorted(set(np.unique(o.record["detected"].values).tolist()))
        return "detected " + ", ".join(f"{c} `{CODE_NAMES[c]}`" for c in codes)
    rec = o.record
    flags = ", ".join(f"`{f}`" for f in rec["flags"]) if rec["flags"] else "no flag"
    null = [k for k in SHOT_KEYS if rec.get(k) is None]
    return f"{flags}; " + (f"null: {_nulls(null)}" if null else "all finite")


def render_markdown(work: Path) -> str:
    """docs/hard_cases.md from the observed outcome of every (case, tier)."""
    lines = [
        "# Hard cases",
        "",
        ("Generated by `tests/test_hard_cases.py` from running every case in every tier that "
        "supports it; do not edit. Regenerate with"),
        "",
        "    CHIRPLIDAR_WRITE_DOCS=1 .venv/bin/python -m pytest tests/test_hard_cases.py",
        "",
        ("The invariant every outcome is held to: every number is finite, or it is null (JSON) / "
        "NaN (files) and a flag says why (a shot: a flag whose definition nulls that output; a "
        "survey: `detected` is not 1 on that shot); never a sentinel value (such as -300 dB); "
        "never a beat outside the processed band without `beat_out_of_band`. What cannot be "
        "simulated faithfully is refused: exit 2 and one line on the command line, never a "
        "traceback. Each case also has its own expected outcome (the *expected* column, its "
        "source in parentheses; the checks themselves are in the test module)."),
        "",
        ("Shots run `chirplidar shot --json` (link, rf) or `chirplidar.api.simulate_shot` "
        "(baseband); surveys run `chirplidar run` on a small mission. ✓: as expected; "
        "✗: a known bug, marked `xfail(strict=True)` (listed below the table); —: the case "
        "does not use that tier."),
        "",
        "| case | what | built from | expected | link | baseband | rf |",
        "|---|---|---|---|---|---|---|",
    ]
    bugs = []
    for case in CASES:
        if case.kind == "pointer":
            continue
        if case.built:
            built = case.built + (f"; `--set {' '.join(case.overrides)}`" if case.overrides else "")
        else:
            built = f"`{Path(case.mission).relative_to(ROOT)}`" + (
                f" `--set {' '.join(case.overrides)}`" if case.overrides else "")
        for tier, extra in case.tier_overrides.items():
            built += f"; {tier}: `--set {' '.join(extra)}`"
        cells = []
        for tier in TIERS:
            if tier not in case.tiers:
                cells.append("—")
                continue
            o = outcome(case, tier, work)
            problems = verdict(case, tier, o)
            mark = "✓" if not problems else "✗"
            cells.append(f"{mark} {summarize(case, tier, o, work)}")
            if problems:
                bugs.append(f"- **{case.name}** ({tier}): {case.xfail.get(tier, 'not marked')}. "
                            f"Observed: {_clean('; '.join(problems), work)}.")
        lines.append(f"| {case.name} | {case.what} | {_clean(built, work)} | "
                     f"{case.expect.describe()} ({case.expect.source}) | " + " | ".join(cells) + " |")
    lines += ["", "## Known bugs (xfail)", ""] + (bugs or ["None."])
    lines += ["", "## Cases run by other test modules", "",
              "| case | what | covered by |", "|---|---|---|"]
    for case in CASES:
        if case.kind == "pointer":
            lines.append(f"| {case.name} | {case.what} | "
                         + "<br>".join(f"`{p}`" for p in case.pointers) + " |")
    return "\n".join(lines) + "\n"


def test_docs_table_is_current(work):
    text = render_markdown(work)
    if os.environ.get(WRITE_DOCS_ENV, "").strip() not in ("", "0"):
        DOCS.write_text(text)
    assert DOCS.is_file(), f"{DOCS} missing: run with {WRITE_DOCS_ENV}=1 to write it"
    assert DOCS.read_text() == text, (f"{DOCS.name} differs from the outcomes: regenerate with "
                                      f"{WRITE_DOCS_ENV}=1 .venv/bin/python -m pytest "
                                      "tests/test_hard_cases.py")
