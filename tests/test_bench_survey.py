"""``chirplidar bench --what survey``: the survey against its ray-casting floor
(:mod:`chirplidar.benchmarks.survey`). Its arithmetic and that it runs; no timed assertion."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from chirplidar.benchmarks import survey as bs
from chirplidar.cli import main
from chirplidar.mission import survey as mission_survey
from chirplidar.mission.preflight import prepare
from conftest import TWO_BEAMS, write_flat_uav_mission

SUBRAYS = 5


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 4 s two-beam UAV line at 20 Hz, 300 m over a flat 4 km scene (50 m grid): 80 shots x 2
    beams, five footprint sub-rays per beam; its own terrain cache."""
    tmp = tmp_path_factory.mktemp("bench_survey")
    mission = write_flat_uav_mission(tmp, "tiny", altitude_m=400.0, beams=TWO_BEAMS, prf=20.0,
                                     stop=4.0, subrays=SUBRAYS)
    return mission, tmp / "cache"


def test_floor_ratio_from_its_parts():
    # Issue 19's own figures: 28 000 shots/s, 8 rays per shot (7 sub-rays and the axis),
    # embree 3.8e6 rays/s per core -> "6 % of that floor".
    assert bs.floor_ratio(28_000.0, 8, 3.8e6) == pytest.approx(28_000.0 * 8 / 3.8e6, rel=1e-15)
    assert round(bs.floor_ratio(28_000.0, 8, 3.8e6), 2) == 0.06
    # a survey that only casts rays, at embree's rate, is at its floor
    assert bs.floor_ratio(3.8e6 / 8, 8, 3.8e6) == pytest.approx(1.0, rel=1e-15)
    for bad in ((0.0, 8, 1e6), (1e4, -1, 1e6), (1e4, 8, math.nan), (1e4, 8, math.inf)):
        with pytest.raises(ValueError, match="must be finite and > 0"):
            bs.floor_ratio(*bad)


def test_ray_recorder_counts_every_ray_and_keeps_whole_calls():
    seen = []
    rec = bs.RayRecorder(lambda t, o, d: seen.append(len(o)) or "hits", max_rays=5)
    rays = [np.arange(3 * k, dtype=float).reshape(k, 3) for k in (3, 4, 2)]
    assert [rec("terrain", r, r + 1.0) for r in rays] == ["hits"] * 3
    assert seen == [3, 4, 2] and rec.n_rays == 9 and rec.terrain == "terrain"
    # whole calls until max_rays (5) are kept: the first two (3 + 4 rays), not the third
    assert [o.shape[0] for o, _ in rec.calls] == [3, 4] and rec.kept == 7
    np.testing.assert_array_equal(rec.calls[1][1], rays[1] + 1.0)


def test_bench_survey_on_a_tiny_mission(tiny, monkeypatch):
    mission, cache = tiny
    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(cache))
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    cast = mission_survey.cast_rays
    lines = []
    res = bs.bench_survey(mission, repeats=2, progress=lines.append)
    # the process's CPUs and the survey module are as they were
    assert mission_survey.cast_rays is cast
    if affinity is not None:
        assert os.sched_getaffinity(0) == affinity and len(res["cpus"]) == 1
    _, _, plan = prepare(mission, cache_dir=cache)
    # shot-beams: the plan's shots times its beams; rays per shot-beam: the axis ray and the
    # footprint's survey.subrays_per_beam sub-rays (mission.survey.chunk_geometry)
    assert res["shots"] == plan.n_shots * plan.beams.n_beams == 80 * 2   # 4 s x 20 Hz
    assert res["rays_per_shot"] == 1 + SUBRAYS and res["subrays_per_beam"] == SUBRAYS
    assert res["rays_timed"] == res["shots"] * res["rays_per_shot"]   # all of them, here
    assert res["repeats"] == 2 and len(res["seconds_all"]) == 2
    assert res["seconds"] == pytest.approx(np.median(res["seconds_all"]), rel=1e-12)
    assert res["embree_rays_per_s"] == pytest.approx(np.median(res["embree_rays_per_s_all"]),
                                                     rel=1e-12)
    assert res["shots_per_s"] == pytest.approx(res["shots"] / res["seconds"], rel=1e-12)
    assert res["floor_ratio"] == pytest.approx(
        res["shots_per_s"] * res["rays_per_shot"] / res["embree_rays_per_s"], rel=1e-12)
    assert res["floor_s"] == pytest.approx(
        res["shots"] * res["rays_per_shot"] / res["embree_rays_per_s"], rel=1e-12)
    stages = res["breakdown_s"]
    assert {"total", "geometry", "ray_casts", "link_tier", "chunk_writes"} <= set(stages)
    assert stages["ray_casts"] <= stages["geometry"] <= stages["total"]
    assert "floor_ratio" in bs.format_survey(res) and len(lines) == 2 + 2


def test_bench_survey_json_keys(tiny, monkeypatch, capsys):
    mission, cache = tiny
    monkeypatch.setenv("CHIRPLIDAR_CACHE", str(cache))
    assert main(["bench", "--what", "survey", "--mission", str(mission), "--json",
                 "--repeats", "1"]) == 0
    rec = json.loads(capsys.readouterr().out)
    keys = ["shots", "rays_per_shot", "seconds", "shots_per_s", "embree_rays_per_s",
            "floor_ratio"]
    assert list(rec)[:6] == keys
    assert all(rec[k] > 0 for k in keys)
    assert rec["repeats"] == 1


def test_bench_survey_refuses_bad_repeats(tiny):
    with pytest.raises(ValueError, match="repeats must be an integer >= 1"):
        bs.bench_survey(tiny[0], repeats=0)
