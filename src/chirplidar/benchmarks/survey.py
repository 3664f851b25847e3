"""``chirplidar bench --what survey``: a link-tier survey run against its ray-casting floor, on
one core.

What bounds a link-tier survey is casting its rays at the terrain. The floor is the raw embree
call alone: a shot-beam casts ``rays_per_shot`` rays (the beam axis plus
``survey.subrays_per_beam`` footprint sub-rays, :func:`..mission.survey.chunk_geometry`), so
no survey can run faster than ``embree_rays_per_s / rays_per_shot`` shot-beams per second, and

    floor_ratio = shots_per_s * rays_per_shot / embree_rays_per_s

is the share of that floor the survey reaches (1: nothing but ray casting).

Everything runs in this process, on one core: the CPU affinity is pinned to one CPU where the
system allows it (Linux), BLAS is limited to one thread (:func:`.._threads.single_threaded_blas`)
and the run uses the serial executor (no Dask). The steps, in order:

1. **warm-up** (untimed): one ``run_mission`` of the mission (tier ``link``) into a temporary
   directory: it fills the terrain cache and pays the imports and first-call costs.
2. **the survey's rays** (untimed): the run's own chunk geometry
   (:func:`..mission.survey.chunk_geometry`, each chunk with its run seed) with the survey
   module's ``cast_rays`` wrapped to record the terrain and every ray it is given, chunk after
   chunk until :data:`MAX_RECORDED_RAYS` (whole calls). The rays counted per shot-beam are
   the ``rays_per_shot`` of the floor (the axis ray and the sub-rays of each shot-beam: 8 for
   the demo's ``subrays_per_beam = 7``), counted in the code as it is rather than assumed.
3. **timed, ``repeats`` rounds**, each: (a) ``seconds``: wall time of one ``run_mission`` call,
   serial, into a temporary directory, from the call to its return: preparation (mission and
   scene load from the filled cache, plan, the scene crossing check), every chunk (geometry and
   its ray casts, the link tier, the per-shot records, the compressed chunk file), the merge
   into the results file, its read-back and the summary; (b) the raw embree call of trimesh
   (``ray_pyembree.RayMeshIntersector(terrain.mesh).intersects_first``; its scene built once,
   untimed) on the recorded rays and the same terrain mesh, in the survey's own calls (its
   batches), summed; (c) embreex called directly on the whole mesh as the project builds it
   (``geometry.raycast.whole_scene(terrain).first_hits``: no trimesh wrapper), the same calls;
   (d) the project's own ``cast_rays`` on the same calls (float64 ranges, per-call crop of a
   heightfield). Interleaving them makes a drift of the machine's speed touch them alike. Each key is the median of its rounds; ``floor_s`` is the run's
   shot-beams times ``rays_per_shot`` over ``embree_rays_per_s``: the seconds of the floor.
4. **breakdown** (optional, untimed): one more run under :mod:`cProfile`, with the cumulative
   seconds of named stages (:data:`STAGES`); cProfile slows Python-level calls, so read them
   as shares, not as the run's seconds.
"""

from __future__ import annotations

import contextlib
import cProfile
import os
import pstats
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

MISSION_NAME = "greenland_uav.toml"
_DATE = "2026-01-01T00:00:00Z"   # fixed date_created: runs are alike
#: Rays kept for the floor's timing (48 bytes each: 96 MB); embree's rate per ray does not
#: change with the batch beyond a few 1e4 rays.
MAX_RECORDED_RAYS = 2_000_000

#: Stages of the breakdown: name -> (file path suffix, function name) pairs whose cumulative
#: seconds add up ("prepare" ... "merge": parts of a run; "ray_casts" is part of "geometry").
STAGES = {
    "total": (("mission/runner.py", "run_mission"),),
    "prepare": (("mission/preflight.py", "prepare"),),
    "geometry": (("mission/survey.py", "chunk_geometry"),),
    "ray_casts": (("geometry/raycast.py", "cast_rays"),),
    "link_tier": (("mission/pipeline.py", "measure_chunk"),),
    "records": (("mission/pipeline.py", "per_shot_variables"),
                ("mission/pipeline.py", "results_dataset")),
    "chunk_writes": (("mission/results/writer.py", "_write_netcdf"),),
    "merge": (("mission/results/merge.py", "append_ready"), ("mission/results/merge.py", "finish"),
              ("mission/results/read.py", "verify_results_file"),
              ("mission/summary.py", "summary_of_chunks")),
}
#: Stages summed from the functions' own time (not cumulative): every profiled entry whose
#: file or name holds the word (pyproj's transforms; embreex's calls are not seen by cProfile:
#: the ray casts' own share is ``floor_s``).
OWN_TIME_STAGES = {"pyproj": "pyproj"}


def floor_ratio(shots_per_s: float, rays_per_shot: float, embree_rays_per_s: float) -> float:
    """``shots_per_s * rays_per_shot / embree_rays_per_s``: the survey's rays per second over
    the raw embree call's (module docstring); every part finite and > 0."""
    parts = {"shots_per_s": shots_per_s, "rays_per_shot": rays_per_shot,
             "embree_rays_per_s": embree_rays_per_s}
    for name, value in parts.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return float(shots_per_s) * float(rays_per_shot) / float(embree_rays_per_s)


@contextlib.contextmanager
def one_core():
    """This process on one CPU (the first it may use; Linux ``sched_setaffinity``, restored on
    exit; elsewhere unchanged) with BLAS limited to one thread. Yields the CPU set used (None
    where affinity cannot be set)."""
    from .._threads import single_threaded_blas

    old = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    cpus = None
    if old:
        cpus = {min(old)}
        os.sched_setaffinity(0, cpus)
    try:
        with single_threaded_blas():
            yield cpus
    finally:
        if old:
            os.sched_setaffinity(0, old)


class RayRecorder:
    """A stand-in for ``cast_rays(terrain, origins, directions)`` that calls it and keeps the
    terrain, the number of rays and a copy of each call's rays (whole calls, until
    ``max_rays`` are kept)."""

    def __init__(self, cast, max_rays: int = MAX_RECORDED_RAYS):
        self.cast = cast
        self.max_rays = int(max_rays)
        self.terrain = None
        self.n_rays = 0
        self.calls: list[tuple[np.ndarray, np.ndarray]] = []
        self.kept = 0

    def __call__(self, terrain, origins_m, directions):
        o = np.array(origins_m, dtype=np.float64).reshape(-1, 3)
        d = np.array(directions, dtype=np.float64).reshape(-1, 3)
        if self.terrain is None:
            self.terrain = terrain
        self.n_rays += o.shape[0]
        if self.kept < self.max_rays and o.shape[0]:
            self.calls.append((o, d))
            self.kept += o.shape[0]
        return self.cast(terrain, origins_m, directions)


def survey_rays(mission, overrides=(), *, max_rays: int = MAX_RECORDED_RAYS) -> dict:
    """The rays a link-tier run of ``mission`` casts: its chunks' geometry
    (:func:`..mission.survey.chunk_geometry` with the run's chunk seeds and
    ``survey.subrays_per_beam``), chunk after chunk until ``max_rays`` rays are kept, with the
    survey module's ``cast_rays`` wrapped by a :class:`RayRecorder`.

    Returns {"terrain", "calls" (the kept calls' (origins, directions)), "kept" (their rays),
    "shot_beams" (of those chunks), "rays" (cast for them), "subrays_per_beam"}."""
    from ..mission import survey as sv_mod
    from ..mission.preflight import prepare

    config, scene, plan = prepare(Path(mission), overrides=list(overrides), tier="link")
    seeds = sv_mod.chunk_seeds(config.seed, plan.n_chunks)
    n_sub = config.survey.subrays_per_beam
    rec = RayRecorder(sv_mod.cast_rays, max_rays)
    shot_beams = 0
    sv_mod.cast_rays = rec
    try:
        for i in range(plan.n_chunks):
            t = plan.chunk_times(i)
            sv_mod.chunk_geometry(plan, scene, config, t, seeds[i], n_sub)
            shot_beams += t.size * plan.beams.n_beams
            if rec.kept >= max_rays:
                break
    finally:
        sv_mod.cast_rays = rec.cast
    return {"terrain": rec.terrain if rec.terrain is not None else scene.terrain,
            "calls": rec.calls, "kept": rec.kept, "shot_beams": shot_beams, "rays": rec.n_rays,
            "subrays_per_beam": int(n_sub)}


def stage_seconds(stats: pstats.Stats) -> dict:
    """Seconds of each of :data:`STAGES` (cumulative) and :data:`OWN_TIME_STAGES` (own time)
    in a profile; stages none of whose functions ran are left out."""
    table = stats.stats  # type: ignore[attr-defined]  (pstats keeps it as a public attribute)
    out: dict[str, float] = {}
    for name, funcs in STAGES.items():
        found = [v[3] for (file, _, func), v in table.items()
                 if any(file.replace(os.sep, "/").endswith(suffix) and func == f
                        for suffix, f in funcs)]
        if found:
            out[name] = float(sum(found))
    for name, word in OWN_TIME_STAGES.items():
        own = [v[2] for (file, _, func), v in table.items() if word in file or word in func]
        if own:
            out[name] = float(sum(own))
    return out


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def bench_survey(mission=None, overrides=(), *, repeats: int = 3, breakdown: bool = True,
                 progress=None) -> dict:
    """The survey against its ray-casting floor (module docstring), on one core.

    Returns {"shots" (shot-beams of the run), "rays_per_shot", "seconds", "shots_per_s",
    "embree_rays_per_s", "floor_ratio"} (medians of ``repeats`` rounds) and "floor_s",
    "mission", "records", "beams", "subrays_per_beam", "repeats", "seconds_all",
    "embree_rays_per_s_all", "embree_scene_rays_per_s" (embreex on the whole mesh),
    "cast_rays_per_s" (the project's ``cast_rays``; both on the same rays), "rays_timed",
    "terrain_faces", "cpus",
    "run_parts_s" (the median run's ``RunResult.timings``) and, with ``breakdown``,
    "breakdown_s" (:func:`stage_seconds` of a profiled run). ``progress(line)``, if given, is
    called after each step."""
    from trimesh.ray import ray_pyembree

    from ..geometry.raycast import cast_rays, embree_available, whole_scene
    from ..mission.runner import run_mission
    from ..mission_files import default_mission_path

    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    if not embree_available():
        raise RuntimeError("bench --what survey needs embreex (pip install embreex)")
    mission = Path(mission) if mission is not None else default_mission_path(MISSION_NAME)
    say = progress if progress is not None else (lambda line: None)
    overrides = list(overrides)

    def run(out: Path):
        res = run_mission(mission, overrides=overrides, tier="link", out=out,
                          date_created=_DATE, workers=None, overwrite=True)
        out.unlink()
        return res

    with one_core() as cpus, tempfile.TemporaryDirectory(prefix="chirplidar-survey-") as tmp:
        out = Path(tmp) / "survey.nc"
        warm_s = _timed(lambda: run(out))
        say(f"warm-up run: {warm_s:.2f} s (untimed)")
        rays = survey_rays(mission, overrides)
        calls, terrain, kept = rays["calls"], rays["terrain"], rays["kept"]
        if kept == 0:
            raise ValueError(f"{mission}: no ray went through mission.survey.cast_rays while "
                             "its chunk geometry was computed (the survey cast none, or casts "
                             "them another way: benchmarks.survey.survey_rays must follow)")
        rays_per_shot = rays["rays"] / rays["shot_beams"]
        inter = ray_pyembree.RayMeshIntersector(terrain.mesh)
        inter.intersects_first(*(a[:1] for a in calls[0]))  # builds trimesh's scene (untimed)
        say(f"{kept} survey rays in {len(calls)} calls recorded ({rays_per_shot:g} per "
            "shot-beam)")
        scene = whole_scene(terrain)   # embreex called directly on the whole mesh (untimed)
        seconds, embree, direct, ours, results = [], [], [], [], []
        for k in range(repeats):
            t = time.perf_counter()
            res = run(out)
            seconds.append(time.perf_counter() - t)
            results.append(res)
            # the survey's calls as it made them (the same batches)
            embree.append(kept / sum(_timed(lambda: inter.intersects_first(o, d))
                                     for o, d in calls))
            direct.append(kept / sum(_timed(lambda: scene.first_hits(o, d)) for o, d in calls))
            ours.append(kept / sum(_timed(lambda: cast_rays(terrain, o, d)) for o, d in calls))
            say(f"round {k + 1}/{repeats}: run {seconds[-1]:.2f} s, embree {embree[-1]:.3g} "
                f"rays/s, cast_rays {ours[-1]:.3g} rays/s")
        parts = None
        if breakdown:
            prof = cProfile.Profile()
            prof.enable()
            try:
                run(out)
            finally:
                prof.disable()
            parts = stage_seconds(pstats.Stats(prof))
    return _assemble(mission, seconds, (embree, direct, ours), results, rays, rays_per_shot,
                     cpus, parts)


def _assemble(mission, seconds, rates, results, rays, rays_per_shot, cpus, parts) -> dict:
    """The result dict of :func:`bench_survey` from its rounds (``rates``: the rounds' rays per
    second of trimesh's embree call, of embreex on the whole mesh, of ``cast_rays``)."""
    embree, direct, ours = rates
    mid = sorted(range(len(seconds)), key=lambda i: seconds[i])[len(seconds) // 2]
    summary = results[mid].summary
    records, beams = int(summary["shots"]), int(summary["beams"])
    sec = statistics.median(seconds)
    emb = statistics.median(embree)
    shots_per_s = records * beams / sec
    rays_per_shot = float(rays_per_shot)
    out = {
        "shots": records * beams, "rays_per_shot": rays_per_shot, "seconds": sec,
        "shots_per_s": shots_per_s, "embree_rays_per_s": emb,
        "floor_ratio": floor_ratio(shots_per_s, rays_per_shot, emb),
        "floor_s": records * beams * rays_per_shot / emb,
        "mission": str(mission), "records": records, "beams": beams,
        "subrays_per_beam": rays["subrays_per_beam"], "repeats": len(seconds),
        "seconds_all": list(seconds), "embree_rays_per_s_all": list(embree),
        "embree_scene_rays_per_s": statistics.median(direct),
        "cast_rays_per_s": statistics.median(ours), "rays_timed": int(rays["kept"]),
        "terrain_faces": int(rays["terrain"].n_faces),
        "cpus": sorted(cpus) if cpus else None, "run_parts_s": dict(results[mid].timings),
    }
    if parts is not None:
        out["breakdown_s"] = parts
    return out


def format_survey(res: dict) -> str:
    """The result of :func:`bench_survey` as text."""
    lines = [
        (f"{res['mission']}: {res['shots']} shot-beams ({res['records']} shots x "
         f"{res['beams']} beam(s)), link tier, one core (CPU {res['cpus']}), median of "
         f"{res['repeats']} runs: {res['seconds']:.2f} s, {res['shots_per_s']:.3g} shot-beams/s"),
        (f"  rays per shot-beam {res['rays_per_shot']:g} (axis + {res['subrays_per_beam']} "
         f"sub-rays); raw embree (trimesh) {res['embree_rays_per_s']:.3g} rays/s, embreex on "
         f"the whole mesh {res['embree_scene_rays_per_s']:.3g}, cast_rays "
         f"{res['cast_rays_per_s']:.3g} ({res['rays_timed']} of the survey's rays, "
         f"{res['terrain_faces']} terrain faces)"),
        (f"  floor {res['floor_s']:.2f} s: floor_ratio {res['floor_ratio']:.3f} (goal >= 0.3)"),
        "  run parts " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in res["run_parts_s"].items()),
    ]
    if "breakdown_s" in res:
        lines.append("  profiled run (cProfile, cumulative) " + ", ".join(
            f"{k} {v:.2f} s" for k, v in res["breakdown_s"].items()))
    return "\n".join(lines)
