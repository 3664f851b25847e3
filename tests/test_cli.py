"""Command line: shot, sweep, bench, sensitivity (in-process through ``main``), start-up."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chirplidar.analysis import sensitivity_at
from chirplidar.cli import main
from chirplidar.cli.common import json_number
from chirplidar.thesis_sensitivity import load_measured, shot_noise_power_dbm, shot_noise_snr_db

ROOT = Path(__file__).resolve().parents[1]
MISSION = str(ROOT / "missions" / "thesis_bench.toml")
# A short, slow-sampled record: rf shots in milliseconds.
SMALL = ["--set", "sims.T=16e-6", "chrp.Tchp=16e-6", "sims.Fs=1.2e9", "chrp.F2=250e6"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def output_names() -> tuple[str, ...]:
    from chirplidar.api import OUTPUT_NAMES
    return tuple(OUTPUT_NAMES)


def strict_json(text: str):
    """json.loads that rejects NaN/Infinity (not JSON)."""
    def bad(token):
        raise ValueError(f"non-JSON constant {token}")
    return json.loads(text, parse_constant=bad)


def is_png(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_MAGIC


# ------------------------------------------------------------------------------------------ shot

def test_shot_json_has_exactly_table_4_10_keys(capsys):
    assert main(["shot", MISSION, "--json", "--tier", "link", "--seed", "3"]) == 0
    rec = strict_json(capsys.readouterr().out)
    assert set(rec) == set(output_names()) | {"flags", "tier", "f_beat_hz"}
    assert list(rec)[:16] == list(output_names())           # Table 4.10 order
    assert rec["tier"] == "link"
    assert isinstance(rec["flags"], list)
    for name in output_names():
        assert rec[name] is None or isinstance(rec[name], float)


def test_shot_rf_json_and_spectrum_plot(tmp_path, capsys):
    png = tmp_path / "spec.png"
    assert main(["shot", MISSION, *SMALL, "--json", "--seed", "1", "--plot", str(png)]) == 0
    rec = strict_json(capsys.readouterr().out)
    assert rec["tier"] == "rf"
    assert set(rec) == set(output_names()) | {"flags", "tier", "f_beat_hz"}
    assert is_png(png)


def test_shot_table_output(capsys):
    assert main(["shot", MISSION, "--tier", "link", "--set", "atm.Pattn=40"]) == 0
    out = capsys.readouterr().out
    for name in output_names():
        assert name in out
    assert "dBm" in out and "flags" in out


def test_shot_plot_on_link_tier_is_refused(tmp_path, capsys):
    # The link tier declares no spectrum (tiers.registry): refused before the shot, as bad input,
    # naming the tiers that draw one.
    png = tmp_path / "none.png"
    code = main(["shot", MISSION, "--tier", "link", "--plot", str(png)])
    assert code == 2
    captured = capsys.readouterr()
    assert "draws no spectrum; use --tier rf or baseband" in captured.err
    assert captured.out == ""
    assert not png.exists()


def test_mission_may_follow_set(capsys):
    assert main(["shot", "--set", "atm.Pattn=20", "sys.rsel=PIN", MISSION, "--tier", "link",
                 "--json"]) == 0
    assert "SNR" in strict_json(capsys.readouterr().out)


def test_unknown_set_key_exits_2_with_suggestion(capsys):
    assert main(["shot", MISSION, "--tier", "link", "--set", "chrp.F3=300e6"]) == 2
    err = capsys.readouterr().err
    assert "chrp.F3" in err and "chrp.F2" in err
    assert "Traceback" not in err


def test_missing_mission_file_exits_2(tmp_path, capsys):
    missing = tmp_path / "nope.toml"
    assert main(["shot", str(missing), "--tier", "link"]) == 2
    assert "nope.toml" in capsys.readouterr().err


def test_bad_option_exits_2(capsys):
    assert main(["shot", MISSION, "--tier", "warp"]) == 2
    assert main(["shot"]) == 2
    assert main(["--help"]) == 0


def test_json_number_null_for_non_finite():
    assert json_number(-math.inf) is None
    assert json_number(math.nan) is None
    assert json_number(np.float64(-3.5)) == -3.5
    assert json_number(4) == 4


# ----------------------------------------------------------------------------------------- sweep

def test_sweep_json_one_object_per_x_and_repeat(capsys):
    code = main(["sweep", MISSION, "--vary", "atm.Pattn", "--start", "20", "--stop", "80",
                 "--n", "3", "--repeat", "2", "--tier", "link", "--seed", "5", "--json",
                 "--no-progress"])
    assert code == 0
    recs = strict_json(capsys.readouterr().out)
    assert isinstance(recs, list) and len(recs) == 6
    for rec in recs:
        assert "x" in rec
        assert set(output_names()) <= set(rec)
    assert sorted({r["x"] for r in recs}) == pytest.approx([20.0, 50.0, 80.0])


def test_sweep_plot_with_thesis_output_names(tmp_path, capsys):
    png = tmp_path / "sweep.png"
    code = main(["sweep", MISSION, "--vary", "atm.Pattn", "--start", "20", "--stop", "100",
                 "--n", "4", "--tier", "link", "--plot", str(png), "--x", "outputs.Psig",
                 "--y", "outputs.CNR"])
    assert code == 0
    out = capsys.readouterr().out
    assert "atm.Pattn" in out
    assert is_png(png)


def test_sweep_unknown_output_name_lists_valid_names(capsys):
    code = main(["sweep", MISSION, "--vary", "atm.Pattn", "--start", "20", "--stop", "80",
                 "--n", "2", "--tier", "link", "--y", "outputs.SNRR"])
    assert code == 2
    err = capsys.readouterr().err
    assert "SNRR" in err and "Psig" in err and "d_rx" in err


def test_sweep_bad_vary_key_or_range_exits_2(capsys):
    base = ["sweep", MISSION, "--start", "20", "--stop", "80", "--n", "2", "--tier", "link"]
    assert main([*base, "--vary", "chrp.F3"]) == 2
    err = capsys.readouterr().err
    assert "chrp.F3" in err and "chrp.F2" in err and "Traceback" not in err
    assert main([*base, "--vary", "atm.Pattn", "--scale", "log", "--start", "-1"]) == 2
    assert "log" in capsys.readouterr().err


def test_sweep_plot_against_varied_key(tmp_path, capsys):
    png = tmp_path / "vs_x.png"
    assert main(["sweep", MISSION, "--vary", "atm.Pattn", "--start", "10", "--stop", "100",
                 "--n", "3", "--scale", "log", "--tier", "link", "--x", "atm.Pattn",
                 "--y", "d_rx", "--plot", str(png), "--no-progress"]) == 0
    assert is_png(png)


# ----------------------------------------------------------------------------- bench/sensitivity

def test_bench_json_keys_positive(capsys):
    assert main(["bench", "--what", "shot", "--json", "--repeats", "1"]) == 0
    rec = strict_json(capsys.readouterr().out)
    assert set(rec) == {"rf_shot_s", "fft_s", "ratio"}
    assert all(v > 0 for v in rec.values())


def test_sensitivity_link_writes_png_and_csv(tmp_path, capsys):
    out = tmp_path / "sensitivity"
    assert main(["sensitivity", "--tier", "link", "--out", str(out), "--points", "5",
                 "--no-progress"]) == 0
    summary = capsys.readouterr().out
    for det in ("homodyne", "direct", "heterodyne"):
        assert det in summary
    assert is_png(out / "fig5_7_sensitivity.png")
    lines = [ln for ln in (out / "fig5_7_sensitivity.csv").read_text().splitlines()
             if not ln.startswith("#")]
    rows = list(csv.DictReader(lines))
    assert len(rows) == 15
    assert {r["detection"] for r in rows} == {"homodyne", "direct", "heterodyne"}
    assert set(output_names()) <= set(rows[0])


def test_demo_is_a_hidden_alias_of_sensitivity(tmp_path, capsys):
    """``demo`` (the former name) says so in one line and runs ``sensitivity``; the help lists
    ``sensitivity`` only."""
    code = main(["demo", "--tier", "link", "--mission", str(tmp_path / "nope.toml"),
                 "--out", str(tmp_path), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines()[0] == "chirplidar demo is now chirplidar sensitivity"
    assert "nope.toml" in err
    assert main(["--help"]) == 0
    listed = capsys.readouterr().out
    assert "sensitivity" in listed and " demo " not in listed


def test_measured_tables_load():
    data = load_measured()
    assert {k: len(v[0]) for k, v in data.items()} == {"direct": 10, "heterodyne": 15,
                                                       "homodyne": 19}


def test_shot_noise_limit_eq_2_6_2():
    # eta P / (2 h nu B) = 10 at P = 10 * 2 h nu B / eta; h nu at 1.31 um = 1.5164e-19 J.
    p_w = 10 * 2 * 6.62607015e-34 * 299792458.0 / 1.31e-6 * 30e3 / 0.85
    assert shot_noise_snr_db(10 * math.log10(p_w) + 30) == pytest.approx(10.0, abs=1e-9)
    assert shot_noise_power_dbm(10.0) == pytest.approx(10 * math.log10(p_w) + 30)


def test_sensitivity_fit_reads_a_line_at_10_db():
    # A coherent receiver's curve is a line of slope 1 (Fig. 5.7): SNR = Psig + 106 reads -96 dBm.
    p = np.linspace(-60.0, -110.0, 11)
    snr = np.maximum(p + 106.0, 6.0)          # the noise-peak floor below ~6 dB stays out of the fit
    value, slope, used = sensitivity_at(p, snr)
    assert value == pytest.approx(-96.0) and slope == pytest.approx(1.0) and used == 5  # 16..36 dB
    assert math.isnan(sensitivity_at(p[:2], snr[:2])[0])


def test_console_script_help():
    res = subprocess.run([sys.executable, "-m", "chirplidar.cli", "--help"], capture_output=True,
                         text=True, check=False)
    assert res.returncode == 0
    assert "shot" in res.stdout and "null" in res.stdout


def test_bench_raycast_json(capsys):
    # Small terrain for speed; the benchmark's default is one million triangles.
    assert main(["bench", "--what", "raycast", "--json", "--triangles", "20000", "--rays", "2000",
                 "--repeats", "1"]) == 0
    rec = strict_json(capsys.readouterr().out)
    assert set(rec) == {"project_rays_per_s", "embree_rays_per_s", "ratio"}
    assert all(v > 0 for v in rec.values())


# -------------------------------------------------------------------------------------- start-up

HEAVY = ("scipy", "xarray", "trimesh", "dask", "matplotlib", "pandas", "pydantic", "shapely")


def _modules_after(code: str) -> list[str]:
    """Top-level packages of :data:`HEAVY` imported by ``python -c code`` (a fresh process)."""
    loaded = "{m.split('.')[0] for m in sys.modules}"
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted({loaded} & {set(HEAVY)!r})))"
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=False)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_import_units_and_help_stay_light():
    """``import chirplidar.units`` and ``chirplidar --help`` import none of the heavy packages
    (the package ``__init__`` and the command line import them on first use)."""
    assert _modules_after("import chirplidar.units") == []
    assert _modules_after("import chirplidar; chirplidar.__version__") == []
    assert _modules_after("from chirplidar.cli import build_parser\n"
                          "build_parser().format_help()") == []


@pytest.mark.parametrize("package", ["geometry", "target", "optics", "atmosphere"])
def test_physics_packages_import_their_modules_on_first_use(package):
    """The physics packages list their names without importing scipy or trimesh; every name of
    ``__all__`` and every submodule is there when read."""
    assert _modules_after(f"import chirplidar.{package}") == []
    code = (f"import chirplidar.{package} as p\n"
            "missing = [n for n in p.__all__ if not hasattr(p, n)]\n"
            "assert not missing and set(p.__all__) <= set(dir(p)), missing\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False)
    assert res.returncode == 0, res.stderr


def test_package_names_load_on_first_use():
    import chirplidar

    from chirplidar import ConfigError, OUTPUT_NAMES, simulate_shot  # noqa: F401
    assert "SNR" in chirplidar.OUTPUT_NAMES and set(chirplidar.__all__) <= set(dir(chirplidar))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        chirplidar.nope  # noqa: B018


def test_bench_startup_json(capsys):
    assert main(["bench", "--what", "startup", "--json", "--repeats", "1"]) == 0
    rec = strict_json(capsys.readouterr().out)
    assert set(rec) == {"help_s", "import_units_s", "python_s", "repeats"}
    assert rec["repeats"] == 1 and all(rec[k] > 0 for k in ("help_s", "import_units_s"))


def test_benchmark_modules_import():
    import importlib

    for name in ("timing", "scale", "coverage", "startup"):
        importlib.import_module(f"chirplidar.benchmarks.{name}")


def test_run_mission_may_follow_set(capsys):
    # As for shot, sweep and study: the mission after a --set list is the mission, not a key.
    uav = str(ROOT / "missions" / "greenland_uav.toml")
    assert main(["run", "--set", "survey.stop_s=1", uav, "--dry-run", "--json"]) == 0
    assert "shots" in strict_json(capsys.readouterr().out)
    assert main(["run", "--set", "survey.stop_s=1"]) == 2
    assert "required: MISSION" in capsys.readouterr().err


def test_api_takes_a_mission_path_and_refuses_an_empty_sweep():
    from chirplidar import api, load_mission

    by_path = api.simulate_shot(MISSION, tier="link")
    by_config = api.simulate_shot(load_mission(MISSION), tier="link")
    assert by_path["SNR"] == by_config["SNR"]
    with pytest.raises(ValueError, match="n \\(points\\) must be an integer >= 1"):
        api.sweep(MISSION, "atm.Pattn", 70, 80, 0)
    with pytest.raises(TypeError, match="mission file's path"):
        api.simulate_mission_shot(load_mission(MISSION))


def test_run_refuses_what_the_survey_tier_does_not_model(capsys):
    # Every survey tier is checked against its declared support before any work (preflight):
    # the link tier has no closed form for squaring recovery (it used to fail mid-run).
    uav = str(ROOT / "missions" / "greenland_uav.toml")
    assert main(["run", uav, "--set", 'processing.doppler_recovery="squaring"',
                 "processing.doppler_max_hz=1e6", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "survey.tier = 'link': the link tier does not model processing.doppler_recovery" in err
    assert err.count("\n") == 1


@pytest.mark.parametrize("what", ["run", "campaign"])
def test_bench_run_refuses_no_workers(what, capsys):
    from conftest import one_line_refusal

    one_line_refusal(["bench", "--what", what, "--workers", "0"], capsys,
                     "--workers must be >= 1", "got 0")
