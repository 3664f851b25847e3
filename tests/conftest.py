from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "missions" / "thesis_bench.toml"
CH5 = ROOT / "missions" / "thesis_ch5_bench.toml"

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
FLAT_SNOW = 'source = "flat"\n[terrain.flat]\nheight_m = 100.0\nmaterial = "snow"'


def write_flat_uav_mission(tmp: Path, name: str, *, altitude_m: float, beams: str, prf: float,
                           stop: float, subrays: int, effects: str = "[]",
                           terrain: str = FLAT_SNOW, extends: Path = FIELD) -> Path:
    """A UAV line (1.6 km along grid x at ``altitude_m``, no jitter) over a 4 km square scene
    (EPSG:3413, 50 m grid, no atmosphere) in ``tmp``: the mission file's path. ``terrain`` is the
    ``[terrain]`` table's source line and its sub-table (flat snow 100 m high by default)."""
    source, _, sub = terrain.partition("\n")
    (tmp / f"{name}_scene.toml").write_text(f"""
name = "{name}"
epsg = 3413
effects = {effects}
[terrain]
{source}
center_lat_deg = 69.0
center_lon_deg = -49.0
size_x_m = 4000.0
size_y_m = 4000.0
resolution_m = 50.0
{sub}
[atmosphere]
cn2_profile = "none"
extinction_per_m = 0.0
scale_height_m = 1200.0
""")
    mission = tmp / f"{name}.toml"
    mission.write_text(f"""
extends = "{extends}"
seed = 5
[scene]
file = "{name}_scene.toml"
[platform]
kind = "uav"
[platform.uav]
coordinates = "scene_centre"
waypoints_m = [[-800.0, 0.0], [800.0, 0.0]]
speed_mps = 20.0
altitude_m = {altitude_m}
altitude_mode = "absolute"
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
""")
    return mission
