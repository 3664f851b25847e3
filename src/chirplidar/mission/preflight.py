"""Before a run flies: the mission loaded and checked, what a planner should be warned about,
and how big the run is.

:func:`prepare` loads and checks everything a run needs before any shot: the resolved
configuration (the mission file with its ``--set`` overrides), its scene (whose ``effects`` list
becomes the run's ``effects.enabled``: a scene enables effects, their parameters come from the
instrument's ``[effects.*]`` sections) and the survey plan.

:func:`planner_warnings` looks at a checked configuration and its scene for values that are
legal but implausible (a power typed in the wrong unit, a platform that cannot point, a flight
longer than the platform's endurance, a line spacing no line fits, a path that skims the
terrain). They are printed before any work and
kept in the results file's ``planner_warnings`` attribute.

:func:`run_estimate` sizes the run: shots, beam-shots, chunks, the disk the results take and the
time, from a short timed pilot of the run's own first shots (its outputs are discarded; the
run's random streams are untouched). A run above :data:`LARGE_RUN_HOURS` or
:data:`LARGE_RUN_GB` needs ``--yes`` (``chirplidar run``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config.loader import ConfigError, config_with, load_mission, scene_overrides
from ..tiers.registry import TIER_NAMES
from . import measure
from .results import BYTES_PER_BEAM_SHOT
from .survey import (flight_section, check_crosses_scene, chunk_geometry, plan_survey,
                     survey_polygon_xy)

#: The tiers a survey runs through: every registered tier.
TIERS = TIER_NAMES

#: A CW chirped lidar's laser above this is suspicious: the thesis's sources are a few mW
#: (8.58 mW, Table 4.4) and a fibre amplifier gives a few W; more is probably mW typed as W.
MAX_PLAUSIBLE_LASER_W = 5.0
#: A Q-switched altimeter's pulse above this is suspicious: GLAS fired 75 mJ, MOLA 45 mJ
#: (thesis Tables 2.1-2.2); 1 J is beyond any flown one (mJ typed as J?).
MAX_PLAUSIBLE_PULSE_J = 1.0
#: A pulsed survey's footprint sampling that reads Gardner's (1992) slope spreading within 1 %
#: (tests/test_pulsed.py): sub-rays out to twice the 1/e^2 half-angle, at least 32 of them.
PULSED_FOOTPRINT_EXTENT = 2.0
PULSED_SUBRAYS = 32
#: Pointing jitter above this (per axis, rms) is more than any survey platform's: small-UAV
#: gimbals hold ~1e-4 rad, aircraft INS-stabilized mounts ~1e-5, ICESat-2 ~1e-5 rad.
MAX_PLAUSIBLE_JITTER_RAD = 1e-2
#: Survey UAVs: fixed-wing ones cruise at 15-35 m/s and stay below a few km (a long-endurance
#: fixed-wing UAV at most ~60 m/s and ~6 km); more is probably a unit typed wrong.
MAX_PLAUSIBLE_UAV_SPEED_MPS = 60.0
MAX_PLAUSIBLE_UAV_ALTITUDE_M = 6000.0
#: Flying lower than this above the terrain anywhere on the path leaves no margin for the
#: terrain model's error (a DEM's metre-level error, a synthetic surface's features).
MIN_CLEARANCE_M = 10.0
#: Runs above these need ``--yes``: hours of computing on the planned cores, or gigabytes.
LARGE_RUN_HOURS = 2.0
LARGE_RUN_GB = 20.0
#: The timed pilot: a first shot cheaper than this is followed by this many shots.
PILOT_CHEAP_S = 0.5
PILOT_SHOTS = 16384


def prepare(mission_path, *, overrides=(), tier=None, seed=None, cache_dir=None):
    """Load and check everything a run needs, before any shot: (config, scene, plan)."""
    from .scene import load_scene

    mission_path = Path(mission_path)
    if mission_path.is_dir():
        raise ConfigError(f"{mission_path}: is a directory, not a mission file")
    if not mission_path.is_file():
        raise ConfigError(f"{mission_path}: mission file does not exist")
    config = load_mission(mission_path, overrides)
    src = str(mission_path)
    if config.scene is None:
        raise ConfigError(f"{src}: a survey run needs a [scene] section with file = "
                          "\"../scenes/NAME.toml\"")
    extra = {}
    if tier is not None:
        if tier not in TIERS:
            raise ConfigError(f"--tier {tier}: choose one of {', '.join(TIERS)}")
        extra["survey.tier"] = tier
    if seed is not None:
        extra["seed"] = int(seed)
    if extra:
        config = config_with(config, extra)
    scene_path = (mission_path.parent / config.scene.file).resolve()
    if not scene_path.is_file():
        raise ConfigError(f"{src}: scene.file: {config.scene.file} does not exist "
                          f"(looked for {scene_path})")
    changes = scene_overrides(config)
    try:
        scene = load_scene(scene_path, cache_dir=cache_dir, overrides=changes)
    except ConfigError as exc:
        if not changes:
            raise
        raise ConfigError(f"{exc} (with the mission's scene keys "
                          f"{', '.join('scene.' + k for k in changes)})") from None
    try:
        config = config_with(config, {"effects.enabled": list(scene.effects)})
    except ConfigError as exc:
        why = str(exc).removeprefix("override: ")
        raise ConfigError(f"{src} with scene {scene_path.name} (effects = "
                          f"{list(scene.effects)}): {why}") from None
    if config.survey is not None:   # what the survey's tier does not model, before any work
        from ..config.instrument import instrument_from_config
        from ..tiers.registry import get_tier

        tier = config.survey.tier
        try:
            get_tier(tier).check(instrument_from_config(config))
        except ValueError as exc:
            raise ConfigError(f"{src}: survey.tier = {tier!r}: {exc}") from None
    if config.survey is not None and config.kind == "pulsed":
        check_pulsed_survey(config, src)
    plan = plan_survey(config, scene, src)
    measure.check_range_window(config, src)
    check_crosses_scene(plan, scene, config, src)
    return config, scene, plan


def check_pulsed_survey(config, src: str) -> None:
    """ConfigError for what a pulsed instrument's survey lacks: its background light, and a
    range window of its own (the digitizer's record is the window)."""
    if config.background is None:
        raise ConfigError(f"{src}: a pulsed instrument's survey needs a [background] section "
                          "(source = 'sun', 'radiance' or 'none'): direct detection counts the "
                          "light in its field of view")
    if config.survey.range_window_m is not None:
        dig = config.digitizer
        raise ConfigError(f"{src}: survey.range_window_m is the chirped receivers' range gate; a "
                          f"pulsed instrument's window is its digitizer's record "
                          f"(digitizer.record_samples = {dig.record_samples} at "
                          f"{dig.sample_rate_hz:g} Hz): remove survey.range_window_m")


class PlannerWarning(UserWarning):
    """A legal but implausible value of a run (printed before any work, kept in the file)."""


def planner_warnings(config, scene, plan) -> list[str]:
    """One sentence for each legal but implausible value of a run (see the module docstring)."""
    out = _instrument_warnings(config)
    jitter = config.attitude.jitter_rad_rms
    if jitter > MAX_PLAUSIBLE_JITTER_RAD:
        out.append(f"attitude.jitter_rad_rms = {jitter:g} rad ({np.degrees(jitter):.3g} deg) "
                   f"per axis is more than any survey platform's pointing jitter (> "
                   f"{MAX_PLAUSIBLE_JITTER_RAD:g} rad): is it in degrees or mrad?")
    out += _flight(config, plan)
    out += _line_spacing(config, scene)
    out += _clearance(config, scene, plan)
    return out


def _instrument_warnings(config) -> list[str]:
    """A power typed in the wrong unit; a receiver that cannot see its beat."""
    out = []
    if config.kind == "pulsed":
        sv = config.survey
        if sv.footprint_extent < PULSED_FOOTPRINT_EXTENT or sv.subrays_per_beam < PULSED_SUBRAYS:
            out.append(f"survey.footprint_extent = {sv.footprint_extent:g} with "
                       f"survey.subrays_per_beam = {sv.subrays_per_beam} samples too little of "
                       "the beam for a pulsed waveform: on a 10 deg slope 7 sub-rays within the "
                       "1/e^2 cone read the pulse spreading 14 % narrow (Gardner 1992); use "
                       f"footprint_extent >= {PULSED_FOOTPRINT_EXTENT:g} and subrays_per_beam >= "
                       f"{PULSED_SUBRAYS}")
        energy = config.pulse.energy_j
        if energy > MAX_PLAUSIBLE_PULSE_J:
            out.append(f"pulse.energy_j = {energy:g} J is more than any altimeter's Q-switched "
                       f"pulse (> {MAX_PLAUSIBLE_PULSE_J:g} J; GLAS's is 75 mJ): is it mJ typed "
                       "as J?")
        return out
    power = config.laser.power_w
    if power > MAX_PLAUSIBLE_LASER_W:
        out.append(f"laser.power_w = {power:g} W is more than a CW chirped lidar's laser "
                   f"(> {MAX_PLAUSIBLE_LASER_W:g} W; the thesis's is 8.58 mW): is it mW typed "
                   "as W?")
    if config.system.receiver == "coherent" and config.balanced.lo_power_w <= 0:
        out.append("balanced.lo_power_w (COH.P_LO) = 0: a coherent receiver without a local "
                   "oscillator detects nothing; every shot will be below the detection threshold")
    if config.waveform.vpp_v <= 0:
        out.append("waveform.vpp_v (chrp.Vpp) = 0: no chirp drives the modulator, so there is "
                   "no beat; every shot will be below the detection threshold")
    return out


def _flight(config, plan) -> list[str]:
    """A flight longer than the platform's endurance; a UAV faster or higher than any."""
    sec = flight_section(config)
    if sec is None:
        return []
    out = []
    key = f"platform.{config.platform.kind}"
    duration = getattr(plan.path, "duration_s", None)
    if sec.endurance_s is not None and duration is not None and duration > sec.endurance_s:
        out.append(f"the path takes {duration:.0f} s, {duration / sec.endurance_s:.3g} times "
                   f"{key}.endurance_s = {sec.endurance_s:g} s: more than one flight")
    if config.platform.kind == "uav":
        if sec.speed_mps > MAX_PLAUSIBLE_UAV_SPEED_MPS:
            out.append(f"{key}.speed_mps = {sec.speed_mps:g} m/s is faster than any survey UAV "
                       f"(> {MAX_PLAUSIBLE_UAV_SPEED_MPS:g} m/s)")
        if sec.altitude_m > MAX_PLAUSIBLE_UAV_ALTITUDE_M:
            out.append(f"{key}.altitude_m = {sec.altitude_m:g} m is higher than any survey UAV "
                       f"flies (> {MAX_PLAUSIBLE_UAV_ALTITUDE_M:g} m): is it in feet or km?")
    return out


def _line_spacing(config, scene) -> list[str]:
    polygon = survey_polygon_xy(config, scene)
    if polygon is None:
        return []
    sec = flight_section(config)
    heading = np.radians(sec.heading_deg) if sec.heading_deg is not None else None
    if heading is None:
        return []
    across = np.array([np.cos(heading), -np.sin(heading)])   # grid (x, y), right of the lines
    width = float(np.ptp(polygon @ across))
    if sec.line_spacing_m > width:
        return [f"platform.{config.platform.kind}.line_spacing_m = {sec.line_spacing_m:g} m is "
                f"wider than the survey polygon across the lines ({width:.0f} m): one line is "
                "flown"]
    return []


def _clearance(config, scene, plan) -> list[str]:
    """The path's lowest height above the terrain, for platforms flown at an absolute height."""
    sec = flight_section(config)
    if sec is None or getattr(sec, "altitude_mode", "absolute") != "absolute":
        return []
    duration = getattr(plan.path, "duration_s", None)
    if not duration:
        return []
    t = np.linspace(0.0, duration, 4001)
    xyh = plan.path.positions(t)
    ground = scene.ground_height_m(xyh[:, 0], xyh[:, 1])
    over = np.isfinite(ground)
    if not over.any():
        return []
    clearance = xyh[over, 2] - ground[over]
    k = int(np.argmin(clearance))
    lowest = float(clearance[k])
    if lowest >= MIN_CLEARANCE_M:
        return []
    where = f"at x = {xyh[over][k, 0]:.0f} m, y = {xyh[over][k, 1]:.0f} m (t = {t[over][k]:.0f} s)"
    key = f"platform.{config.platform.kind}.altitude_m"
    if lowest < 0:
        return [f"{key} = {sec.altitude_m:g} m (absolute) flies {-lowest:.0f} m below the "
                f"terrain {where}, over {100 * np.mean(clearance < 0):.0f} % of the path over the "
                "scene: the shots there look up from inside the ground; raise it or use "
                "altitude_mode = 'above_ground'"]
    return [f"{key} = {sec.altitude_m:g} m (absolute) passes {lowest:.1f} m above the terrain "
            f"{where} (< {MIN_CLEARANCE_M:g} m)"]


@dataclass(frozen=True)
class RunEstimate:
    """The size of a run (see :func:`run_estimate`)."""

    shots: int
    beams: int
    chunks: int
    pilot_shots: int
    seconds_per_shot: float    # one core, from the pilot
    seconds_per_chunk: float   # a chunk's fixed cost (tables, set-up), one core
    cores: int
    disk_bytes: int            # uncompressed: the file is smaller (zlib)

    @property
    def seconds(self) -> float:
        one_core = self.shots * self.seconds_per_shot + self.chunks * self.seconds_per_chunk
        return one_core / min(self.cores, self.chunks)

    @property
    def large(self) -> bool:
        return self.seconds > LARGE_RUN_HOURS * 3600 or self.disk_bytes > LARGE_RUN_GB * 1e9

    def as_dict(self) -> dict:
        return {"shots": self.shots, "beams": self.beams, "beam_shots": self.shots * self.beams,
                "chunks": self.chunks, "cores": self.cores,
                "estimated_seconds": self.seconds, "estimated_disk_bytes_at_most": self.disk_bytes,
                "pilot_shots": self.pilot_shots}


def run_estimate(config, scene, plan, *, cores: int = 1, pilot_chunk) -> RunEstimate:
    """The run's size and its time on ``cores`` cores, timed on a pilot of its first shots.

    ``pilot_chunk(config, scene, geometry, seq)`` is a chunk's work after its geometry
    (measurement, dataset, compressed file: :func:`.pipeline.pilot_chunk`); the pilot times it
    with the geometry. The first shot is timed twice (the first call also imports and fills
    caches); an expensive one (>= :data:`PILOT_CHEAP_S`: rf, baseband) is taken as the cost
    of every shot. Cheap shots (the link tier) cost less per shot in large
    batches and a chunk has a fixed cost (tables, files): a run of at most
    ``2 * PILOT_SHOTS`` shots is timed whole, a larger one on ``PILOT_SHOTS / 4`` (twice: the
    first also fills caches) and ``PILOT_SHOTS`` shots, whose difference gives the cost per
    shot (the larger pilot's mean when timing noise makes it no larger). The merge's copying
    is not timed (a few per cent). The pilot has its own seed: the run's outputs do not depend
    on it.
    """
    t_first = plan.chunk_times(0)
    seq = np.random.SeedSequence(0)

    def timed(n: int) -> float:
        start = time.perf_counter()
        geom = chunk_geometry(plan, scene, config, t_first[:n], seq,
                              config.survey.subrays_per_beam)
        pilot_chunk(config, scene, geom, seq)
        return time.perf_counter() - start

    timed(1)   # the first call also pays for imports and caches (netCDF's, the tables')
    one = timed(1)
    per_shot, per_chunk, pilot = one, 0.0, 1
    if one < PILOT_CHEAP_S and plan.n_shots > 1:
        if plan.n_shots <= 2 * PILOT_SHOTS:
            pilot = min(plan.n_shots, t_first.size)
            per_shot = timed(pilot) / pilot
        else:
            pilot = min(PILOT_SHOTS, t_first.size)   # (a first chunk may be shorter)
            small = max(1, pilot // 4)
            timed(small)
            t_small, t_big = timed(small), timed(pilot)
            per_shot = (t_big - t_small) / (pilot - small)
            if not per_shot > 0.5 * t_big / pilot:
                per_shot = t_big / pilot
            per_chunk = max(t_small - small * per_shot, 0.0)
    beams = plan.beams.n_beams
    return RunEstimate(shots=plan.n_shots, beams=beams, chunks=plan.n_chunks,
                       pilot_shots=pilot, seconds_per_shot=per_shot, seconds_per_chunk=per_chunk,
                       cores=max(int(cores), 1),
                       disk_bytes=int(plan.n_shots * beams * BYTES_PER_BEAM_SHOT))


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _size(n_bytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.3g} {unit}"
    return f"{n_bytes:.0f} B"


def format_estimate(est: RunEstimate) -> str:
    """One line: ``159 000 shots x 1 beam in 8 chunks: about 7 s on 1 core ...``."""
    def plural(n, word):
        return f"{n:,} {word}{'s' if n != 1 else ''}".replace(",", " ")

    return (f"{plural(est.shots, 'shot')} x {plural(est.beams, 'beam')} in "
            f"{plural(est.chunks, 'chunk')}: about {_duration(est.seconds)} on "
            f"{plural(est.cores, 'core')} (timed on {plural(est.pilot_shots, 'shot')}), at most "
            f"{_size(est.disk_bytes)} on disk")
