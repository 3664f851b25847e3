from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "missions" / "thesis_bench.toml"
CH5 = ROOT / "missions" / "thesis_ch5_bench.toml"
GLAS_BENCH = ROOT / "missions" / "glas_bench.toml"
PHOTON_COUNTING = ["pulse_receiver.detector=photon_counting", "photon_counting.detection_efficiency=0.5",
                   "photon_counting.dead_time_s=3e-9", "photon_counting.dark_count_rate_hz=1e3"]

# A small, fast configuration of the same physics (16 us record at 1.2 GS/s) for statistics.
SMALL = ["sims.T=16e-6", "chrp.Tchp=16e-6", "sims.Fs=1.2e9", "chrp.F2=250e6", "atm.dst=300",
         "COH.f_LO=2e8"]


@pytest.fixture
def bench_path():
    return BENCH


@pytest.fixture
def ch5_path():
    return CH5


FIELD = ROOT / "missions" / "thesis_field_instrument.toml"
FLAT_SNOW = 'flat height_m = 100.0\nmaterial = "snow"'
TWO_BEAMS = 'pattern = "custom"\noff_nadir_deg = [0.0, 20.0]\nazimuth_deg = [90.0, 90.0]'


def write_scene(tmp: Path, name: str, terrain: str, *, epsg: int = 3413, lat=69.0, lon=-49.0,
                size=4000.0, res=50.0, effects="[]", stem: str | None = None) -> Path:
    """A square scene file ``<stem or name>.toml`` in ``tmp`` (no atmosphere): ``terrain`` is
    the terrain source and its table's lines, e.g. ``'flat height_m = 100.0\nmaterial =
    "snow"'``."""
    p = tmp / f"{stem or name}.toml"
    source, params = terrain.split(" ", 1)
    p.write_text(f"""
name = "{name}"
epsg = {epsg}
effects = {effects}
[terrain]
source = "{source}"
center_lat_deg = {lat}
center_lon_deg = {lon}
size_x_m = {size}
size_y_m = {size}
resolution_m = {res}
[terrain.{source}]
{params}
[atmosphere]
cn2_profile = "none"
extinction_per_m = 0.0
scale_height_m = 1200.0
""")
    return p


def write_uav_mission(tmp: Path, scene: Path, name: str = "m", *, altitude=1000.0,
                      mode="absolute", beams=TWO_BEAMS, waypoints="[[-800.0, 0.0], [800.0, 0.0]]",
                      polygon=None, extra="", extends=FIELD, stop="10.0", subrays=7,
                      prf=20.0) -> Path:
    """A UAV survey ``<name>.toml`` in ``tmp`` over ``scene`` (no jitter, link tier): the
    ``waypoints`` line, or a lawnmower over ``polygon`` (lines 200 m apart along grid x)."""
    path = (f"survey_polygon_m = {polygon}\nline_spacing_m = 200.0\nheading_deg = 90.0"
            if polygon else f"waypoints_m = {waypoints}")
    p = tmp / f"{name}.toml"
    p.write_text(f"""
extends = "{extends}"
seed = 5
[scene]
file = "{scene.name}"
[platform]
kind = "uav"
[platform.uav]
coordinates = "scene_centre"
{path}
speed_mps = 20.0
altitude_m = {altitude}
altitude_mode = "{mode}"
[attitude]
roll_deg = 0.0
pitch_deg = 0.0
yaw_deg = 0.0
jitter_rad_rms = 0.0
[beams]
{beams}
[survey]
tier = "link"
prf_hz = {prf}
start_s = 0.0
stop_s = {stop}
epoch_utc = "2026-07-01T00:00:00Z"
detection_threshold_db = 10.0
subrays_per_beam = {subrays}
{extra}
""")
    return p


def write_flat_uav_mission(tmp: Path, name: str, *, altitude_m: float, beams: str, prf: float,
                           stop: float, subrays: int, effects: str = "[]",
                           terrain: str = FLAT_SNOW, extends: Path = FIELD) -> Path:
    """A UAV line (1.6 km along grid x at ``altitude_m``, no jitter) over a 4 km square scene
    (EPSG:3413, 50 m grid, no atmosphere) in ``tmp``: the mission file's path. ``terrain`` as
    :func:`write_scene`'s (flat snow 100 m high by default)."""
    scene = write_scene(tmp, name, terrain, effects=effects, stem=f"{name}_scene")
    return write_uav_mission(tmp, scene, name, altitude=altitude_m, beams=beams, prf=prf,
                             stop=stop, subrays=subrays, extends=extends)


def reference_target(config, **overrides):
    """``config`` aimed at the survey's ideal reference target (rho = 1 at normal incidence, a
    beam fully intercepted, no transmission losses, no effects): the link tier's table nodes
    (``tiers.link_survey``)."""
    from chirplidar.config.loader import config_with

    return config_with(config, {
        "channel.free_space": True, "channel.target_radius_m": 1e9,
        "channel.target_reflectivity": 1.0, "channel.atmospheric_transmission": 1.0,
        "channel.optical_transmission": 1.0, "channel.extra_attenuation_db": 0.0,
        "effects.enabled": [], **overrides})


def apd_circuit_variance(apd, bandwidth_hz: float, fs_hz: float, *, white: bool = False):
    """An [apd] section's circuit noise (thesis Table 4.7 terms, eqs. 2.5.1-2.5.5: thermal
    4 k T / R, amplifier i_n^2 + e_n^2 |Y|^2, leakage shot 2 q I_s) referred to the primary
    photocurrent (/ M^2), over the noise bandwidth 1 / (4 sqrt(pi) sigma_h) of a Gaussian
    response of -3 dB ``bandwidth_hz`` (at most fs / 2), as primary electrons^2 per sample
    (x dt^2 / q^2): written out here independently of the tier. ``white``: over fs / 2
    instead, S dt / (2 q^2), the variance per sample of the white noise the response filters."""
    import numpy as np

    from chirplidar.units import BOLTZMANN_J_K, ELEMENTARY_CHARGE_C as Q

    thermal = 4 * BOLTZMANN_J_K * (apd.feedback_temperature_k / apd.feedback_resistance_ohm
                                   + apd.detector_temperature_k / apd.dynamic_resistance_ohm)
    y2 = (1 / apd.feedback_resistance_ohm + 1 / apd.dynamic_resistance_ohm) ** 2 + (
        2 * np.pi * apd.center_frequency_hz
        * (apd.detector_capacitance_f + apd.feedback_capacitance_f)) ** 2
    amp = apd.amp_current_noise_a_per_rthz**2 + apd.amp_voltage_noise_v_per_rthz**2 * y2
    psd = (thermal + amp + 2 * Q * apd.leakage_current_a) / apd.gain**2
    band = fs_hz / 2
    if not white:
        sigma_h = np.sqrt(np.log(2)) / (2 * np.pi * bandwidth_hz)
        band = min(1 / (4 * np.sqrt(np.pi) * sigma_h), band)
    return psd * band / (fs_hz * Q) ** 2


def one_line_refusal(argv, capsys, *needles) -> str:
    """Run the command line; it must exit 2 with one stderr line (no traceback) holding every
    needle. Returns that line."""
    from chirplidar import cli

    code = cli.main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def write_small_uav(tmp: Path) -> Path:
    """The Greenland UAV mission over a coarse (50 m) copy of its scene, 30 s of flight at
    100 Hz = 3000 shots in 6 chunks of 500: ``small_uav.toml`` (and ``scene.toml``) in
    ``tmp``, the mission's path."""
    text = (ROOT / "scenes" / "greenland_outlet.toml").read_text()
    text = text.replace("resolution_m = 5.0", "resolution_m = 50.0", 1)
    assert "resolution_m = 50.0" in text
    (tmp / "scene.toml").write_text(text)
    mission = tmp / "small_uav.toml"
    mission.write_text(f'extends = "{ROOT / "missions" / "greenland_uav.toml"}"\n'
                       '[scene]\nfile = "scene.toml"\n'
                       '[survey]\nstop_s = 30.0\nchunk_shots = 500\n')
    return mission


def netcdf_header(path) -> list:
    """Everything netCDF stores about a file except the data: dimensions, variables with
    dtype, dimensions, filters, chunking and typed attributes, typed global attributes."""
    import netCDF4

    with netCDF4.Dataset(path) as d:
        out = [("dims", [(k, len(v)) for k, v in d.dimensions.items()]),
               ("attrs", [(k, type(d.getncattr(k)).__name__, repr(d.getncattr(k)))
                          for k in d.ncattrs()])]
        for name, v in d.variables.items():
            out.append((name, str(v.dtype), v.dimensions, v.filters(), v.chunking(),
                        [(k, type(v.getncattr(k)).__name__, repr(v.getncattr(k)))
                         for k in v.ncattrs()]))
    return out


def identical_files(a, b) -> None:
    """Two results files hold the same data, attributes, encoding and layout."""
    import xarray as xr

    from chirplidar.mission.results import read_netcdf

    xr.testing.assert_identical(read_netcdf(a), read_netcdf(b))
    assert netcdf_header(a) == netcdf_header(b)
