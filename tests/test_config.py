import pytest

from chirplidar.config import ConfigError, THESIS_TABLE, load_mission, resolve_key
from chirplidar.config.loader import PROJECT_KEYS
from conftest import BENCH


def test_every_thesis_name_maps_to_a_project_key():
    for thesis, key, _, _ in THESIS_TABLE:
        assert key in PROJECT_KEYS, (thesis, key)


def test_thesis_names_and_values_are_accepted_by_set():
    cfg = load_mission(BENCH, ["chrp.F2=250e6", "sys.rsel=PIN", "sys.CxMode=het", "atm.state=on",
                               "sys.MxMode=FM"])
    assert cfg.waveform.f_stop_hz == 250e6
    assert cfg.system.receiver == "pin"
    assert cfg.system.coherent_mode == "heterodyne"
    assert cfg.channel.free_space is True


def test_bench_file_holds_the_table_defaults():
    cfg = load_mission(BENCH)
    # Thesis Tables 4.1, 4.3, 4.4, 4.8 (spot checks across tables).
    assert cfg.n_samples == 192_000                      # T = 64 us, Fs = 3 GHz
    assert (cfg.waveform.f_start_hz, cfg.waveform.f_stop_hz) == (100e6, 300e6)
    assert cfg.laser.power_w == 8.58e-3
    assert cfg.balanced.lo_power_w == 2e-3
    assert cfg.channel.free_space is False               # atm.state = off


def test_unknown_set_key_lists_close_matches():
    with pytest.raises(ConfigError) as err:
        load_mission(BENCH, ["chrp.F3=1e8"])
    assert "chrp.F3" in str(err.value) and "chrp.F2" in str(err.value)


def test_unknown_key_in_file_names_file_and_path(tmp_path):
    text = BENCH.read_text().replace("rbw_hz = 30e3", "rbw_hz = 30e3\nrbw_hzz = 1")
    p = tmp_path / "m.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_mission(p)
    assert str(p) in str(err.value) and "processing.rbw_hzz" in str(err.value)


def test_missing_physical_key_is_an_error(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(BENCH.read_text().replace("power_w = 8.58e-3", ""))
    with pytest.raises(ConfigError, match=r"laser.power_w.*lsr.Po"):
        load_mission(p)


def test_f2_above_nyquist_is_a_clear_error():
    with pytest.raises(ConfigError, match="Nyquist"):
        load_mission(BENCH, ["chrp.F2=1.6e9"])


def test_extends_overrides_key_by_key(tmp_path):
    child = tmp_path / "child.toml"
    child.write_text(f'extends = "{BENCH}"\n[laser]\npower_w = 1e-3\n')
    cfg = load_mission(child)
    assert cfg.laser.power_w == 1e-3 and cfg.laser.wavelength_m == 1.31e-6


def test_resolve_key():
    assert resolve_key("atm.Pattn") == "channel.extra_attenuation_db"
    assert resolve_key("channel.distance_m") == "channel.distance_m"


def test_readme_mapping_table_matches_the_alias_table():
    from conftest import ROOT

    readme = (ROOT / "README.md").read_text()
    for thesis, key, unit, table in THESIS_TABLE:
        assert f"| `{thesis}` | `{key}` | {unit} | {table} |" in readme, thesis


def test_effects_switch_is_the_enabled_list():
    with pytest.raises(ConfigError, match="phase_noise"):
        load_mission(BENCH, ["lsr.Lw=1e4"])
    with pytest.raises(ConfigError, match=r"\[effects.doppler\] is missing"):
        load_mission(BENCH, ['effects.enabled=["doppler"]'])
    cfg = load_mission(BENCH, ['effects.enabled=["doppler"]', "effects.doppler.radial_velocity_mps=2"])
    assert cfg.effects.doppler.radial_velocity_mps == 2.0


def test_config_with_fills_an_absent_optional_section():
    from chirplidar.config import config_with

    cfg = config_with(load_mission(BENCH), {"effects.speckle.cells": 4, "effects.enabled": ["speckle"]})
    assert cfg.effects.speckle.cells == 4


def test_binary_mission_file_is_one_clear_error(tmp_path):
    path = tmp_path / "results.nc"
    path.write_bytes(b"\x89HDF\r\n\x1a\n\x00\xff\xfe")
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        load_mission(path)


def test_epoch_given_as_a_toml_date_time():
    """``--set survey.epoch_utc=2026-08-15T12:00:00Z`` is a TOML date-time, not a string: it is
    the same instant; a local time without a zone is refused."""
    from pathlib import Path

    mission = Path(__file__).resolve().parents[1] / "missions" / "greenland_uav.toml"
    cfg = load_mission(mission, ["survey.epoch_utc=2026-08-15T14:00:00+02:00"])
    assert cfg.survey.epoch_utc == "2026-08-15T12:00:00Z"
    with pytest.raises(ConfigError, match="time zone"):
        load_mission(mission, ["survey.epoch_utc=2026-08-15T12:00:00"])
