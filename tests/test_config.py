import math
import os
import re
import subprocess
import sys
import typing

import pytest
from pydantic.fields import FieldInfo

from chirplidar.config import ConfigError, THESIS_TABLE, config_with, load_mission, resolve_key
from chirplidar.config.keys import iter_fields
from chirplidar.config.loader import PROJECT_KEYS
from chirplidar.config.models import PULSED_SECTIONS, MissionConfig
from chirplidar.config.scene import SceneConfig, read_scene_config
from chirplidar.geometry.terrain import MATERIAL_NAMES
from conftest import BENCH, GLAS_BENCH, PHOTON_COUNTING, ROOT


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


def test_the_documented_thesis_name_table_is_the_alias_table():
    # The docs site's thesis-name page is generated from config.aliases (docs/hooks.py): every
    # alias the loader accepts appears there with its project key, unit and thesis table.
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = hooks.thesis_names_page()
    for thesis, key, unit, table in THESIS_TABLE:
        row = next((line for line in page.splitlines() if f"`{thesis}`" in line), None)
        assert row is not None, thesis
        assert f"`{key}`" in row and str(table) in row, row


def test_effects_switch_is_the_enabled_list():
    with pytest.raises(ConfigError, match="phase_noise"):
        load_mission(BENCH, ["lsr.Lw=1e4"])
    with pytest.raises(ConfigError, match=r"\[effects.doppler\] is missing"):
        load_mission(BENCH, ['effects.enabled=["doppler"]'])
    cfg = load_mission(BENCH, ['effects.enabled=["doppler"]',
                               "effects.doppler.radial_velocity_mps=2"])
    assert cfg.effects.doppler.radial_velocity_mps == 2.0


def test_config_with_fills_an_absent_optional_section():
    cfg = config_with(load_mission(BENCH), {"effects.speckle.cells": 4,
                                            "effects.enabled": ["speckle"]})
    assert cfg.effects.speckle.cells == 4


def test_binary_mission_file_is_one_clear_error(tmp_path):
    path = tmp_path / "results.nc"
    path.write_bytes(b"\x89HDF\r\n\x1a\n\x00\xff\xfe")
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        load_mission(path)


def test_epoch_given_as_a_toml_date_time():
    """``--set survey.epoch_utc=2026-08-15T12:00:00Z`` is a TOML date-time, not a string: it is
    the same instant; a local time without a zone is refused."""
    mission = GREENLAND
    cfg = load_mission(mission, ["survey.epoch_utc=2026-08-15T14:00:00+02:00"])
    assert cfg.survey.epoch_utc == "2026-08-15T12:00:00Z"
    with pytest.raises(ConfigError, match="time zone"):
        load_mission(mission, ["survey.epoch_utc=2026-08-15T12:00:00"])


# ------------------------------------------------------------------ one configuration layer
GREENLAND = ROOT / "missions" / "greenland_uav.toml"
SCENE = ROOT / "scenes" / "greenland_outlet.toml"
SCENE_ENTRIES = {"materials": MATERIAL_NAMES}
#: The keys where inf means something (no signal; a Kolmogorov screen; a uniform atmosphere).
INF_KEYS = {"channel.extra_attenuation_db", "effects.turbulence.outer_scale_m",
            "atmosphere.scale_height_m"}


def _numeric(info: FieldInfo) -> bool:
    args = [a for a in (typing.get_args(info.annotation) or (info.annotation,))
            if a is not type(None)]
    return bool(args) and all(a in (int, float) for a in args)


def _accepts_inf(info: FieldInfo) -> bool:
    return any(getattr(m, "allow_inf_nan", False) for m in info.metadata)


def _is_power(key: str) -> bool:
    """A power in W (``_w``), a power density (``_w_per_rthz``) or a ratio of powers."""
    leaf = key.rsplit(".", 1)[-1]
    return bool(re.search(r"(^|_)w($|_per_)", leaf)) or "power" in leaf


MISSION_FIELDS = dict(iter_fields(MissionConfig))
SCENE_FIELDS = dict(iter_fields(SceneConfig, "", SCENE_ENTRIES))
POWER_KEYS = sorted(k for k in [*MISSION_FIELDS, *SCENE_FIELDS] if _is_power(k))
BENCH_SECTIONS = set(MissionConfig.model_fields) - {"scene", "platform", "attitude", "beams",
                                                    "survey"}


def test_the_power_keys_are_found_by_walking_the_schemas():
    assert {"laser.power_w", "balanced.lo_power_w", "balanced.saturation_power_w",
            "balanced.nep_w_per_rthz", "pin.nep_w_per_rthz"} <= set(POWER_KEYS)
    assert all(_numeric({**MISSION_FIELDS, **SCENE_FIELDS}[k]) for k in POWER_KEYS)


def _mission_for(key: str):
    section = key.split(".")[0]
    if section in PULSED_SECTIONS + ("background",):
        return GLAS_BENCH
    return BENCH if section in BENCH_SECTIONS else GREENLAND


def _refused_naming(key: str, err: ConfigError) -> str:
    msg = str(err)
    assert "\n" not in msg and f"'{key}'" in msg, msg
    return msg


@pytest.mark.parametrize("value", [math.inf, math.nan, -1.0], ids=["inf", "nan", "minus1"])
@pytest.mark.parametrize("key", POWER_KEYS)
def test_a_bad_power_is_a_one_line_configuration_error(key, value):
    """``--set lsr.Po=inf``, nan or a negative power anywhere: refused, naming the key."""
    mission = _mission_for(key)
    with pytest.raises(ConfigError) as err:
        load_mission(mission, {key: value})
    _refused_naming(key, err.value)
    with pytest.raises(ConfigError) as err:
        config_with(load_mission(mission), {key: value})
    _refused_naming(key, err.value)


@pytest.mark.parametrize("key", POWER_KEYS)
def test_a_power_of_zero_is_allowed_where_the_schema_says_ge_0(key):
    info = MISSION_FIELDS[key]
    zero_ok = any(getattr(m, "ge", None) == 0 for m in info.metadata)
    if zero_ok:
        assert config_with(load_mission(_mission_for(key)), {key: 0.0}) is not None
    else:
        with pytest.raises(ConfigError):
            config_with(load_mission(_mission_for(key)), {key: 0.0})


@pytest.mark.parametrize("value", ["inf", "nan", "-1"])
@pytest.mark.parametrize("key", [*POWER_KEYS, "lsr.Po", "COH.P_LO", "PIN.Nep"])
def test_a_bad_power_through_the_command_line(key, value, capsys):
    from chirplidar import cli

    project = resolve_key(key)
    code = cli.main(["shot", str(BENCH), "--set", f"{key}={value}"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("chirplidar shot: ") and f"'{project}'" in lines[0], err
    if key != project:
        assert f"({key})" in lines[0], err


@pytest.mark.parametrize("assignment", ["lsr.Po=inf", "COH.P_LO=nan", "laser.power_w=-1"])
def test_a_bad_power_in_a_fresh_process(assignment):
    """The installed entry point, as a user runs it: exit 2, one line, no traceback."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    res = subprocess.run([sys.executable, "-m", "chirplidar.cli", "shot", str(BENCH),
                          "--set", assignment], capture_output=True, text=True, env=env,
                         timeout=120)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "'laser.power_w' (lsr.Po)" in lines[0] or "'balanced.lo_power_w' (COH.P_LO)" in \
        lines[0], lines[0]


def test_inf_is_allowed_on_three_keys_only():
    allowed = {k for k, f in {**MISSION_FIELDS, **SCENE_FIELDS}.items() if _accepts_inf(f)}
    assert allowed == INF_KEYS


@pytest.mark.parametrize("key", sorted(k for k, f in MISSION_FIELDS.items() if _numeric(f)))
def test_every_number_of_a_mission_refuses_nan_and_inf(key):
    pulsed = key.split(".")[0] in PULSED_SECTIONS + ("background",)
    # The pulsed keys on GLAS flown over Greenland, with a photon-counting detector's section.
    base = load_mission(GREENLAND, [f"instrument={ROOT / 'instruments' / 'glas.toml'}",
                                    *PHOTON_COUNTING, "background.source=radiance",
                                    "background.radiance_w_m2_sr_m=1.0"] if pulsed else [])
    for value in (math.nan, math.inf, -math.inf):
        if value == math.inf and key in INF_KEYS:
            continue
        with pytest.raises(ConfigError) as err:
            config_with(base, {key: value})
        msg = _refused_naming(key, err.value)
        assert f"'{key}'" in msg and ("not a number" in msg or "finite" in msg or
                                      "greater than" in msg), msg


@pytest.mark.parametrize("key", sorted(k for k, f in SCENE_FIELDS.items() if _numeric(f)))
def test_every_number_of_a_scene_refuses_nan_and_inf(key):
    text = SCENE.read_text()
    for value in (math.nan, math.inf, -math.inf):
        if value == math.inf and key in INF_KEYS:
            continue
        with pytest.raises(ConfigError) as err:
            read_scene_config(text, "scene.toml", {key: value})
        msg = str(err.value)
        assert "\n" not in msg and f"{key}: " in msg, msg
        assert "not a number" in msg or "finite" in msg or "greater than" in msg, msg


def test_a_table_where_a_value_belongs_names_the_key():
    """The message named no key before (``Input should be a valid number``): a mission and a
    scene both name it now."""
    with pytest.raises(ConfigError, match=r"'laser.power_w' \(lsr.Po\): Input should be a "
                       r"valid number$"):
        load_mission(BENCH, {"laser.power_w": {"x": 1}})
    with pytest.raises(ConfigError, match=r"atmosphere.extinction_per_m: Input should be a "
                       r"valid number$"):
        read_scene_config(SCENE.read_text(), "scene.toml", {"atmosphere.extinction_per_m":
                                                            {"x": 1}})


def test_missions_and_scenes_share_one_base_model_and_one_formatter():
    from chirplidar.config.base import StrictModel
    from chirplidar.config.keys import section_model

    def models(model):
        yield model
        for info in model.model_fields.values():
            sub = section_model(info.annotation)
            if sub is not None:
                yield from models(sub[1])

    every = [*models(MissionConfig), *models(SceneConfig)]
    assert all(issubclass(m, StrictModel) for m in every)
    assert all(m.model_config["allow_inf_nan"] is False for m in every)
    with pytest.raises(ConfigError, match=r"unknown key 'lsr.Pox' \(did you mean: lsr.Po"):
        load_mission(BENCH, {"lsr.Pox": 1.0})
    with pytest.raises(ConfigError, match=r"scene.toml: atmosphere.extincton_per_m: unknown key "
                       r"\(did you mean: atmosphere.extinction_per_m"):
        read_scene_config(SCENE.read_text(), "scene.toml", {"atmosphere.extincton_per_m": 1.0})


def test_effect_names_come_from_one_list():
    from chirplidar.channel.effects import EFFECTS
    from chirplidar.config.models_effects import EFFECT_NAMES, Effects

    enabled = typing.get_args(typing.get_args(Effects.model_fields["enabled"].annotation)[0])
    assert enabled == EFFECT_NAMES == tuple(EFFECTS)
    assert set(Effects.model_fields) - {"enabled"} <= set(EFFECT_NAMES)
    with pytest.raises(ConfigError, match=r"effects: unknown effect\(s\) \['lava'\]; known: "
                       + ", ".join(EFFECT_NAMES)):
        read_scene_config(SCENE.read_text(), "scene.toml", {"effects": ["lava"]})
