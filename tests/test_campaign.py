"""Satellite campaigns: a TLE's passes over the scene in a window, each flown where its beams
can reach the terrain, one or more chunks per pass; bad campaign input is one clear line."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from chirplidar.config.loader import ConfigError
from chirplidar.mission import preflight, survey
from chirplidar.mission.results import read_netcdf
from chirplidar.mission.runner import run_mission

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = ROOT / "missions" / "icesat2_campaign.toml"
MONTH = ["survey.stop_utc=2026-11-04T00:00:00Z"]   # 30 days of the 91


@pytest.fixture(scope="module")
def month(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    return preflight.prepare(CAMPAIGN, overrides=MONTH, cache_dir=cache)


def _hits(plan, scene, cfg, t):
    g = survey.chunk_geometry(plan, scene, cfg, np.asarray(t, float),
                              np.random.SeedSequence(0), 1)
    return np.isfinite(g.range_true_m).any(axis=1)


def test_every_pass_is_flown_where_its_beams_reach_the_scene(month):
    """Ray casting, independent of the pass search: every pass's shots hit the terrain
    somewhere, and no beam hits it in the 5 s before or after the pass's segment (nothing of
    the scene is left out); chunks never span two passes; tracks number the passes."""
    cfg, scene, plan = month
    starts = plan.pass_starts_s
    assert starts is not None and len(starts) >= 3
    track = plan.track_of(plan.t_s)
    assert np.array_equal(np.unique(track), np.arange(len(starts)))
    for k in range(len(starts)):
        t = plan.t_s[track == k]
        assert _hits(plan, scene, cfg, t[::50]).any()
        outside = np.concatenate([t[0] - np.linspace(0.05, 5.0, 100),
                                  t[-1] + np.linspace(0.05, 5.0, 100)])
        assert not _hits(plan, scene, cfg, outside).any()
    for i in range(plan.n_chunks):
        assert np.unique(plan.track_of(plan.chunk_times(i))).size == 1
        assert plan.chunk_times(i).size <= cfg.survey.chunk_shots


def test_one_pass_campaign_runs_and_counts(tmp_path):
    """An hour around the 2026-10-08 ascending pass (chirplidar passes: 16:23:51 UTC): one
    track in the file, shot times on the PRF clock, ranges held (|error| < 10 m)."""
    res = run_mission(CAMPAIGN, overrides=["survey.start_utc=2026-10-08T16:00:00Z",
                                           "survey.stop_utc=2026-10-08T17:00:00Z"],
                      out=tmp_path / "pass.nc", cache_dir=tmp_path / "cache")
    ds = read_netcdf(res.path)
    assert set(np.unique(ds["track"].values)) == {0}
    t = ds["delta_time"].values[0]
    assert np.allclose(np.diff(t), 1e-4)                 # survey.prf_hz = 10 kHz
    # 2026-10-08T16:23:51 is 3 d 16 h 23 min 51 s after epoch_utc 2026-10-05T00:00:00Z
    assert t[0] < 3 * 86400 + 16 * 3600 + 23 * 60 + 51 < t[-1] + 5
    det = ds["detected"].values == 1
    assert det.any() and np.max(np.abs(ds["range_error"].values[det])) < 10.0


@pytest.mark.parametrize(("overrides", "match"), [
    (["survey.stop_utc=2027-03-01T00:00:00Z"], r"reaches 14\d\.\d days from the TLE epoch"),
    (["survey.start_s=0"], "either a campaign window"),
    (["survey.stop_utc=2026-10-01T00:00:00Z"], "is not after survey.start_utc"),
    (["survey.stop_utc=2026-10-05T00:30:00Z"], "no pass over the scene"),
    (["survey.start_utc=2026-10-05T00:00:00"], "give the time zone"),
])
def test_bad_campaign_input(overrides, match, tmp_path):
    with pytest.raises(ConfigError, match=match):
        preflight.prepare(CAMPAIGN, overrides=overrides, cache_dir=tmp_path / "cache")


def test_campaign_window_is_for_satellites(tmp_path):
    with pytest.raises(ConfigError, match="a uav campaign is several flights"):
        preflight.prepare(ROOT / "missions" / "greenland_uav.toml",
                          overrides=["survey.start_utc=2026-10-05T00:00:00Z",
                                     "survey.stop_utc=2026-10-06T00:00:00Z"],
                          cache_dir=tmp_path / "cache")


def test_shot_finds_a_campaign_shot_in_its_own_pass(month, tmp_path):
    """`chirplidar shot --at-s T` on a campaign: chunks start with each pass (not every
    chunk_shots), so the shot at T is looked up by the plan's chunk starts."""
    from chirplidar.mission.shot import mission_shot_config

    cfg, scene, plan = month
    last = np.flatnonzero(plan.track_of(plan.t_s) == len(plan.pass_starts_s) - 1)[::20]
    g = survey.chunk_geometry(plan, scene, cfg, plan.t_s[last], np.random.SeedSequence(0), 1)
    k = int(last[np.flatnonzero(np.isfinite(g.range_true_m[:, 0]))[0]])   # beam 0 on terrain
    assert plan.locate(k)[0] > 0 and plan.locate(k)[1] != k % cfg.survey.chunk_shots
    shot = mission_shot_config(CAMPAIGN, tier="link", at_s=float(plan.t_s[k]),
                               overrides=MONTH)
    assert shot.geometry["shot_index"] == k
    assert shot.geometry["t_s"] == pytest.approx(plan.t_s[k])


def _tle_checksum(line: str) -> str:
    """A TLE line's first 68 characters with its checksum: the digits' sum, each '-' counting 1,
    modulo 10 (the TLE format)."""
    body = line[:68]
    return body + str(sum(int(c) if c.isdigit() else c == "-" for c in body) % 10)


def test_resume_refuses_a_changed_tle(tmp_path, monkeypatch):
    """Issue 15: a TLE changed between a stopped run and --resume is refused, naming it (the
    element set is part of the mission's resolved configuration, whose hash the manifest
    holds)."""
    from test_run_scale import _interrupted

    line2 = tomllib.loads(CAMPAIGN.read_text())["platform"]["tle"]["line2"]
    mission = tmp_path / "pass.toml"

    def write(second_line):
        mission.write_text(f'extends = "{CAMPAIGN}"\n[platform.tle]\nline2 = "{second_line}"\n'
                           '[survey]\nstart_utc = "2026-10-08T16:00:00Z"\n'
                           'stop_utc = "2026-10-08T17:00:00Z"\nchunk_shots = 5000\n')

    write(line2)
    small = SimpleNamespace(mission=mission, cache=tmp_path / "cache")
    out, _ = _interrupted(small, tmp_path, monkeypatch, after=1)
    # the mean motion's last digit changed: another element set, still checksummed
    changed = _tle_checksum(line2[:62] + str((int(line2[62]) + 1) % 10) + line2[63:])
    write(changed)
    with pytest.raises(ConfigError, match=r"--resume: .*platform\.tle\.line2 = "):
        run_mission(mission, out=out, cache_dir=small.cache, resume=True)
    write(line2)                                     # the same element set again: resumes
    res = run_mission(mission, out=out, cache_dir=small.cache, resume=True)
    assert res.summary["shots"] > 5000
