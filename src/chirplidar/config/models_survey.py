"""Survey sections of a mission: where the instrument flies (scene, platform, attitude, beams)
and what to run. Optional in a transceiver-only mission file; ``chirplidar run`` needs them all
(:mod:`chirplidar.mission.survey` checks)."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from ..tiers.registry import TIER_NAMES
from .base import StrictModel

#: Beams of a custom pattern: every shot casts each beam's sub-rays (ICESat-2 has 6, a
#: multi-beam scanner a few dozen).
MAX_BEAMS = 64
#: A chunk holds ~2 kB per shot and beam with 7 sub-rays (measured on the Greenland UAV demo:
#: 0.35 GB at 20 000 shots, 0.63 GB at 159 000), so a million shots is ~2 GB per beam.
MAX_CHUNK_SHOTS = 1_000_000

XY = tuple[float, float]


class SceneRef(StrictModel):
    """The scene the mission flies over. Any other key of the section changes the scene file's
    key of that name for this mission (``[scene.atmosphere] ground_cn2_m_minus_2_3 = 1e-13``,
    ``--set scene.terrain.flat.material=blue_ice``); the scene loader validates them."""

    model_config = ConfigDict(extra="allow", frozen=True, validate_default=True)

    file: str = Field(description="scene TOML file, relative to the mission file (scenes/*.toml)")


def _check_polygon(points, key: str):
    from shapely import is_valid_reason
    from shapely.geometry import Polygon

    if len(points) < 3:
        raise ValueError(f"{key} needs at least 3 vertices, got {len(points)}")
    poly = Polygon(points)
    if not poly.is_valid:
        raise ValueError(f"{key} is not a simple polygon ({is_valid_reason(poly)}); "
                         "self-intersecting survey outlines are refused")
    if poly.area <= 0:
        raise ValueError(f"{key} has zero area")


class _Survey2D(StrictModel):
    """A path as waypoints, or a lawnmower pattern over a polygon (x, y in ``coordinates``)."""

    coordinates: Literal["scene_centre", "projected"] = Field(
        description="'scene_centre': x, y in metres east/north (grid) of the scene centre; "
        "'projected': absolute x, y of the scene's EPSG frame")
    waypoints_m: tuple[XY, ...] | None = Field(None, description="path vertices (x, y) [m]")
    survey_polygon_m: tuple[XY, ...] | None = Field(
        None, description="area to cover with a lawnmower pattern (x, y) [m]")
    line_spacing_m: float | None = Field(None, gt=0, description="lawnmower line spacing")
    heading_deg: float | None = Field(None, description="lawnmower line direction, clockwise "
                                      "from grid north")

    @model_validator(mode="after")
    def _one_path(self):
        kind = type(self).__name__.lower().replace("platform", "")
        if (self.waypoints_m is None) == (self.survey_polygon_m is None):
            raise ValueError(f"platform.{kind}: give exactly one of waypoints_m and "
                             "survey_polygon_m")
        if self.waypoints_m is not None and len(self.waypoints_m) < 2:
            raise ValueError(f"platform.{kind}.waypoints_m needs at least 2 points")
        if self.survey_polygon_m is not None:
            _check_polygon(self.survey_polygon_m, f"platform.{kind}.survey_polygon_m")
            if self.line_spacing_m is None or self.heading_deg is None:
                raise ValueError(f"platform.{kind}.survey_polygon_m needs line_spacing_m and "
                                 "heading_deg")
        return self


class UavPlatform(_Survey2D):
    speed_mps: float = Field(gt=0, description="ground speed along the path")
    altitude_m: float = Field(description="flight height: above the terrain or above the WGS-84 "
                              "ellipsoid, per altitude_mode")
    altitude_mode: Literal["above_ground", "absolute"]
    max_climb_mps: float | None = Field(None, gt=0, description="above_ground: largest climb "
                                        "rate; with max_descent_mps the UAV flies the lowest "
                                        "profile at least altitude_m above the ground that "
                                        "keeps within both (omitted: follows the ground "
                                        "exactly)")
    max_descent_mps: float | None = Field(None, gt=0, description="above_ground: largest "
                                          "descent rate")
    endurance_s: float | None = Field(None, gt=0, description="longest flight the platform can "
                                      "make (a run warns beyond it; plan keeps within it)")
    turn_radius_m: float | None = Field(None, gt=0, description="smallest turn radius: the "
                                        "path turns at its waypoints; plan refuses lines "
                                        "closer than twice it (no U-turn between them)")

    @model_validator(mode="after")
    def _climb_limits(self):
        if self.altitude_mode == "above_ground" and self.altitude_m <= 0:
            raise ValueError(f"platform.uav.altitude_m = {self.altitude_m:g} m with altitude_mode "
                             "= 'above_ground' is not above the ground: give a height > 0")
        if (self.max_climb_mps is None) != (self.max_descent_mps is None):
            raise ValueError("platform.uav.max_climb_mps and max_descent_mps go together")
        if self.max_climb_mps is not None and self.altitude_mode != "above_ground":
            raise ValueError("platform.uav.max_climb_mps / max_descent_mps shape an "
                             "above_ground profile (altitude_mode = 'above_ground')")
        return self


class AircraftPlatform(_Survey2D):
    speed_mps: float = Field(gt=0, description="ground speed")
    altitude_m: float = Field(description="flight height above the WGS-84 ellipsoid")
    turn_radius_m: float = Field(gt=0, description="radius of the turns joining the lines")
    endurance_s: float | None = Field(None, gt=0, description="longest flight the platform can "
                                      "make (a run warns beyond it; plan keeps within it)")


class OrbitPlatform(StrictModel):
    """Keplerian elements with J2 drift; the orbit is placed so its nadir point passes the scene
    centre at t = 0 (the RAAN and the anomaly are solved for, on the chosen pass)."""

    altitude_m: float = Field(gt=100e3, le=36_000e3, description="height of the satellite "
                              "above the WGS-84 ellipsoid where its nadir crosses the scene "
                              "centre (t = 0); low Earth orbit up to geostationary height")
    eccentricity: float = Field(ge=0, lt=0.1)
    inclination_deg: float = Field(gt=0, lt=180)
    pass_direction: Literal["ascending", "descending"]
    j2: bool = Field(True, description="secular J2 drift of the node and perigee")


class TlePlatform(StrictModel):
    """A two-line element set propagated with SGP4; the run's t = 0 is ``survey.epoch_utc``,
    which must lie within ``TLE_MAX_AGE_DAYS`` of the element set's epoch."""

    line1: str = Field(description="TLE line 1 (69 characters, with its checksum)")
    line2: str = Field(description="TLE line 2 (69 characters, with its checksum)")


class Platform(StrictModel):
    kind: Literal["uav", "aircraft", "satellite"]
    uav: UavPlatform | None = None
    aircraft: AircraftPlatform | None = None
    orbit: OrbitPlatform | None = None
    tle: TlePlatform | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        given = [k for k in ("uav", "aircraft", "orbit", "tle") if getattr(self, k) is not None]
        wanted = {"uav": ["uav"], "aircraft": ["aircraft"],
                  "satellite": [["orbit"], ["tle"]]}[self.kind]
        ok = given in wanted if self.kind == "satellite" else given == wanted
        if not ok:
            need = "[platform.orbit] or [platform.tle]" if self.kind == "satellite" \
                else f"[platform.{self.kind}]"
            raise ValueError(f"platform.kind = '{self.kind}' needs exactly {need}; "
                             f"found {['platform.' + g for g in given] or 'none'}")
        return self


class AttitudeConfig(StrictModel):
    """Platform attitude (intrinsic Z-Y-X: yaw, pitch, roll) and pointing jitter."""

    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    jitter_rad_rms: float = Field(ge=0, description="pointing jitter per axis (rms)")
    doppler_steering: bool = Field(False, description="pitch every shot so its beams are "
                                   "perpendicular to the velocity (zero Doppler shift, as "
                                   "ICESat-2 steers), on top of pitch_deg")


class Beams(StrictModel):
    """Beam pattern: nadir, three ICESat-2-like pairs, a conical scan, or a custom list."""

    pattern: Literal["nadir", "paired", "conical", "custom"]
    pair_spacing_deg: float | None = Field(None, gt=0, description="paired: across-track angle "
                                           "between pair centres")
    within_pair_deg: float | None = Field(None, gt=0, description="paired: angle between the "
                                          "two beams of a pair")
    stagger_deg: float = Field(0.0, ge=0, description="paired: along-track angle between the "
                               "two beams of a pair (the left one ahead)")
    pair_power_ratio: float = Field(1.0, gt=0, description="paired: transmitted power of each "
                                    "pair's left (strong) beam over its right (weak) one")
    cone_half_angle_deg: float | None = Field(None, gt=0, lt=60, description="conical: "
                                              "off-nadir angle")
    scan_rate_deg_s: float | None = Field(None, description="conical: azimuth rate")
    off_nadir_deg: tuple[float, ...] | None = Field(None, max_length=MAX_BEAMS,
                                                    description="custom: per beam")
    azimuth_deg: tuple[float, ...] | None = Field(None, max_length=MAX_BEAMS,
                                                  description="custom: per beam, from "
                                                  "the flight direction towards the right")

    @model_validator(mode="after")
    def _needs(self):
        need = {"nadir": (), "paired": ("pair_spacing_deg", "within_pair_deg"),
                "conical": ("cone_half_angle_deg", "scan_rate_deg_s"),
                "custom": ("off_nadir_deg", "azimuth_deg")}[self.pattern]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"beams.pattern = '{self.pattern}' needs "
                             f"{', '.join('beams.' + k for k in missing)}")
        if self.pattern == "paired":
            if self.within_pair_deg >= self.pair_spacing_deg:
                raise ValueError(f"beams.within_pair_deg ({self.within_pair_deg:g}) must be "
                                 f"smaller than beams.pair_spacing_deg ({self.pair_spacing_deg:g})"
                                 ": the pairs would overlap")
            widest = self.pair_spacing_deg + self.within_pair_deg / 2 + self.stagger_deg
            if widest >= 60:
                raise ValueError(f"beams.pair_spacing_deg + within_pair_deg / 2 + stagger_deg "
                                 f"= {widest:g} deg: the outer beams must stay within 60 deg of "
                                 "nadir (as custom and conical beams)")
        if self.pattern == "custom":
            if len(self.off_nadir_deg) != len(self.azimuth_deg) or not self.off_nadir_deg:
                raise ValueError("beams.off_nadir_deg and beams.azimuth_deg must be non-empty "
                                 "lists of equal length")
            if any(not 0 <= a < 60 for a in self.off_nadir_deg):
                raise ValueError("beams.off_nadir_deg must lie in [0, 60) degrees")
        return self


def _utc(text: str):
    import datetime as _dt

    return _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))


class SurveyRun(StrictModel):
    """What to run: shot clock, time span, tier, detection, footprint sampling, chunking."""

    tier: Literal[TIER_NAMES] = Field(  # type: ignore[valid-type]
        description="the fidelity tier; omitted = the instrument's own: 'pulsed' for a pulsed "
        "instrument, 'link' for a chirped one")
    prf_hz: float = Field(gt=0, description="record (shot) rate; each record averages "
                          "processing.averages chirps (sys.avg). Omitted = the instrument's "
                          "own: pulse.prf_hz, or the record rate 1 / (processing.averages x "
                          "waveform.chirp_period_s)")
    start_s: float | None = Field(None, description="first shot time, s after the path start "
                                  "(UAV, aircraft) or after epoch_utc (satellite: a design "
                                  "orbit's nadir crosses the scene centre then)")
    stop_s: float | None = Field(None, description="end of the span; omitted = the end of the "
                                 "path (UAV, aircraft only)")
    epoch_utc: str = Field(description="ISO 8601 UTC date-time of t = 0 (the results' time origin)")
    start_utc: str | None = Field(None, description="satellite campaign: window start (ISO 8601 "
                                  "UTC); the run flies every pass over the scene until stop_utc, "
                                  "instead of start_s..stop_s")
    stop_utc: str | None = Field(None, description="satellite campaign: window end (ISO 8601 "
                                 "UTC)")
    detection_threshold_db: float = Field(description="SNR in the RBW a return needs to count "
                                          "as detected (the thesis quotes sensitivity at 10 dB)")
    doppler_compensation: Literal["none", "lo_offset"] = Field(
        "none", description="'lo_offset': each beam's local oscillator is shifted by the Doppler "
        "shift predicted from the platform velocity and the beam's nominal pointing (an "
        "acousto-optic shifter per beam), leaving what pointing jitter adds; 'none': the "
        "shift acts (see also attitude.doppler_steering)")
    range_window_m: float | None = Field(None, gt=0, description="width of the range window: "
                                         "the reference delay follows each beam's range "
                                         "predicted to the scene's mid-height surface, as an "
                                         "altimeter's range gate does; returns outside it are "
                                         "flagged (omitted: system.reference_delay_s or its "
                                         "sys.fmaxopt rule)")
    subrays_per_beam: int = Field(ge=1, le=512, description="footprint samples per beam")
    footprint_extent: float = Field(
        1.0, ge=0.5, le=4.0, description="how far the footprint's sub-rays reach, in the beam's "
        "1/e^2 half-angles: 1 samples the 1/e^2 cone (86 % of the power); a pulsed waveform's "
        "width needs the Gaussian's tails: 2 with 32 or more sub-rays reads Gardner's (1992) "
        "slope spreading within 1 % (tests/test_pulsed.py), 1 with 7 sub-rays 10-14 % narrow")
    chunk_shots: int = Field(20000, ge=1, le=MAX_CHUNK_SHOTS, description="shots per chunk "
                             "(memory bound and "
                             "resume granularity)")

    @field_validator("epoch_utc", "start_utc", "stop_utc", mode="before")
    @classmethod
    def _epoch(cls, v):
        import datetime as _dt

        if v is None:
            return v
        if isinstance(v, _dt.datetime):   # --set survey.epoch_utc=2026-08-15T12:00:00Z (TOML)
            if v.tzinfo is None:
                raise ValueError(f"give the time zone (a Z for UTC): {v.isoformat()}")
            v = v.astimezone(_dt.timezone.utc).isoformat().replace("+00:00", "Z")
        if not isinstance(v, str):
            raise ValueError(f"expected an ISO 8601 date-time string, got {v!r}")
        try:
            t = _dt.datetime.fromisoformat(v.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"not an ISO 8601 date-time: {v!r}") from None
        if t.tzinfo is None:
            raise ValueError(f"give the time zone (a Z for UTC): {v!r}")
        return v

    @model_validator(mode="after")
    def _span(self):
        if (self.start_utc is None) != (self.stop_utc is None):
            raise ValueError("survey.start_utc and survey.stop_utc go together (a campaign "
                             "window)")
        if self.start_utc is not None:
            if _utc(self.stop_utc) <= _utc(self.start_utc):
                raise ValueError(f"survey.stop_utc ({self.stop_utc}) is not after "
                                 f"survey.start_utc ({self.start_utc})")
            return self
        if self.start_s is None:
            raise ValueError("survey.start_s is required (or, for a satellite, a campaign "
                             "window: survey.start_utc and stop_utc)")
        if self.stop_s is not None and self.stop_s < self.start_s:
            raise ValueError(f"survey.stop_s ({self.stop_s}) is before survey.start_s "
                             f"({self.start_s})")
        return self
