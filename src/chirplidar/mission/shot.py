"""One shot of a survey mission at the mission's own geometry (``chirplidar shot`` and ``sweep``
on a mission with ``[scene]``, ``[platform]``, ``[attitude]``, ``[beams]`` and ``[survey]``).

A survey mission's instrument file describes the lab bench (``channel.distance_m`` is a fiber
spool); evaluating that configuration as it stands would report the bench, not the flight. Here
the shot is taken from the survey itself, as ``chirplidar run`` computes it (exactly so for the
rf and link tiers; the baseband tier takes the shot's own aim and the rf shot's stream, where a
run aims a batch of neighbouring shots at their median range and gate):

1. the mission is prepared as a run prepares it (:func:`preflight.prepare`: configuration with the
   scene's effects, scene, plan);
2. the shot: by default the first shot time of the span (``plan.t_s``) whose beam ``beam`` hits
   the terrain, searched chunk by chunk; ``at_s`` picks the shot nearest to that time instead
   (an error if its beam has no surface). The geometry is that of the run's chunk holding the
   shot (:func:`survey.chunk_geometry` over the whole chunk, with the chunk's own SeedSequence:
   the same pointing jitter and the same footprint cone, whose size follows the chunk's median
   range, and ``survey.subrays_per_beam`` footprint sub-rays);
3. the footprint's returns as the run computes them for the tier, with the chunk's effect
   streams: ``channel.footprint.received`` (link) or ``channel.footprint.footprint_returns``
   (rf, baseband: without the speckle effect's power draw, which the sub-rays' own speckle
   fields replace);
4. the tier's :class:`~chirplidar.tiers.model.Returns`, as the run builds them for that shot:
   the footprint's power-weighted mean range R0, its received power, the shot's Doppler shift
   when the scene enables Doppler and the run's range gate. The rf and baseband tiers take the
   footprint's echoes and their gain (:func:`measure.rf_shot_returns`, the function
   ``measure_rf`` calls for every shot) and, by default, the shot's own rf stream; the link tier
   takes the mean return (``measure_link`` reads the same closed form from its (range,
   attenuation) node table).

What the link tier returns is its closed form for that configuration: with ``channel.carrier_phase
= "random"`` the mean over a uniform carrier phase (the run multiplies each shot's SNR by its own
fading draw, ``tiers.link.carrier_fading_factor``), and the line of the footprint's mean range
(the run divides by the footprint-spread factor g, ``measure`` module docstring; g - 1 < 1e-3
for the shipped missions). Its P_sig is the run's ``received_power`` (with the speckle effect's
power draw when the scene enables speckle). The rf tier's P_sig is the record's own: the
footprint's power times the echoes' gain, i.e. with the sub-rays' speckle (the rf run's
``received_power`` column holds the speckle-free mean power; equal without speckle).

Seeds: chunk ``c`` draws from child ``c`` of the root SeedSequence ``SeedSequence(seed)``, as
``chirplidar run`` does (pointing jitter, the effects' draws such as speckle), and the tier from
the shot's own stream (the run's rf stream of that shot) unless a generator is given
(``api.sweep_mission`` gives each point its own, as ``api.sweep`` does).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..channel.footprint import footprint_returns, received, shot_doppler_hz
from ..channel.lab import lab_budget
from ..config.instrument import instrument_from_config
from ..config.loader import ConfigError
from ..tiers.echoes import Echoes
from ..tiers.model import Instrument, Returns
from ..tiers.registry import TIER_NAMES, TIERS
from . import measure
from .survey import chunk_geometry

#: Geometry keys added to a mission shot's outputs (``t_s`` [s] of the mission clock, ``beam``,
#: ``shot_index`` in the plan, ``range_m`` true range of the beam axis to the surface,
#: ``footprint_range_m`` power-weighted mean range of the footprint (the returns' ``range_m``;
#: ``d_error`` is relative to it), ``x_m``/``y_m``/``surface_height_m`` the
#: beam axis's hit in the scene frame, ``surface`` its material, ``incidence_deg`` and
#: ``off_nadir_deg``, ``platform_height_m`` ellipsoidal height of the platform).
GEOMETRY_KEYS = ("t_s", "beam", "shot_index", "range_m", "footprint_range_m", "x_m", "y_m",
                 "surface_height_m", "surface", "incidence_deg", "off_nadir_deg",
                 "platform_height_m")
GEOMETRY_UNITS = {"t_s": "s", "range_m": "m", "footprint_range_m": "m", "x_m": "m", "y_m": "m",
                  "surface_height_m": "m", "incidence_deg": "degree", "off_nadir_deg": "degree",
                  "platform_height_m": "m"}


@dataclass(frozen=True)
class Prepared:
    """A prepared survey mission (:func:`preflight.prepare`) and the name used in messages."""

    config: object
    scene: object
    plan: object
    source: str


@dataclass(frozen=True)
class MissionShot:
    """One survey shot as the run evaluates it: the tier's input and the shot's geometry.

    ``instrument`` and ``returns``: the tier's input (the returns carry the footprint's echoes
    for the rf and baseband tiers, the mean return for the link tier); ``seq``/``flat``: the
    chunk's SeedSequence and the shot-beam's flat index in the chunk (shot x beams + beam),
    which name its random stream (:meth:`rng`); ``geometry``: the :data:`GEOMETRY_KEYS`.
    """

    instrument: Instrument
    returns: Returns
    tier: str
    seq: np.random.SeedSequence
    flat: int
    geometry: dict

    def rng(self) -> np.random.Generator:
        """The shot's own stream: the one the run's rf tier draws this shot from."""
        return measure.rf_shot_stream(self.seq, self.flat)


def is_survey(config) -> bool:
    """True for a survey mission (it has a ``[survey]`` section)."""
    return getattr(config, "survey", None) is not None


def prepare_mission(mission, *, overrides=(), seed=None, cache_dir=None) -> Prepared:
    """:func:`preflight.prepare` of the mission file ``mission`` (with ``--set`` style
    ``overrides`` and an optional ``seed``), or ``mission`` itself when it is already a
    :class:`Prepared`."""
    if isinstance(mission, Prepared):
        return mission
    from .preflight import prepare

    config, scene, plan = prepare(mission, overrides=overrides, seed=seed, cache_dir=cache_dir)
    return Prepared(config, scene, plan, str(mission))


def _chunk_seq(root: np.random.SeedSequence, index: int) -> np.random.SeedSequence:
    """Child ``index`` of ``root``: for ``root = SeedSequence(seed)`` the run's chunk seed
    (``survey.chunk_seeds(seed, n)[index]``), whatever the number of chunks."""
    return np.random.SeedSequence(entropy=root.entropy,
                                  spawn_key=tuple(root.spawn_key) + (int(index),))


def _geometry(prep: Prepared, root, index: int):
    config, scene, plan = prep.config, prep.scene, prep.plan
    seq = _chunk_seq(root, index)
    try:
        geom = chunk_geometry(plan, scene, config, plan.chunk_times(index), seq,
                              config.survey.subrays_per_beam)
    except ValueError as exc:
        raise ConfigError(f"{prep.source}: [platform]: {exc}") from None
    return geom, seq


def locate_shot(prep: Prepared, *, at_s=None, beam: int = 0, root=None):
    """(chunk geometry, chunk SeedSequence, shot index in the chunk, shot index in the plan) of
    the evaluated shot: the shot nearest to ``at_s`` [s], or the first of the span whose beam
    ``beam`` hits the terrain. ConfigError (one line) for a beam index out of range, a time
    outside the span, or a beam with no surface."""
    plan, src = prep.plan, prep.source
    n_beams = plan.beams.n_beams
    if isinstance(beam, bool) or not isinstance(beam, (int, np.integer)) \
            or not 0 <= int(beam) < n_beams:
        raise ConfigError(f"{src}: --beam {beam}: the mission has {n_beams} beam(s) "
                          f"(beams.pattern = '{prep.config.beams.pattern}'): use 0..{n_beams - 1}")
    beam = int(beam)
    root = np.random.SeedSequence(prep.config.seed) if root is None else root
    t = np.asarray(plan.t_s)
    if t.size == 0:
        raise ConfigError(f"{src}: the survey span has no shots (survey.start_s .. stop_s at "
                          f"survey.prf_hz)")
    if at_s is not None:
        at_s = float(at_s)
        half = 0.5 / prep.config.survey.prf_hz
        if not (math.isfinite(at_s) and t[0] - half <= at_s <= t[-1] + half):
            raise ConfigError(f"{src}: --at-s {at_s:g}: outside the survey span "
                              f"{t[0]:g} .. {t[-1]:g} s (survey.start_s .. stop_s)")
        k = int(np.argmin(np.abs(t - at_s)))
        c, i = plan.locate(k)
        geom, seq = _geometry(prep, root, c)
        if not np.isfinite(geom.range_true_m[i, beam]):
            x, y, h = geom.platform_xyh[i]
            raise ConfigError(f"{src}: --at-s {at_s:g}: beam {beam} of the shot at t = "
                              f"{t[k]:g} s has no surface under it (platform at x {x:.0f} m, "
                              f"y {y:.0f} m, height {h:.0f} m; the beam misses the scene)")
        return geom, seq, i, k
    # The run's chunks in turn: each one's geometry is exactly the run's (jitter, footprint cone).
    for c in range(plan.n_chunks):
        geom, seq = _geometry(prep, root, c)
        hits = np.flatnonzero(np.isfinite(geom.range_true_m[:, beam]))
        if hits.size:
            i = int(hits[0])
            return geom, seq, i, plan.chunk_start(c) + i
    raise ConfigError(f"{src}: beam {beam} hits the terrain at no shot of the survey span "
                      f"{t[0]:g} .. {t[-1]:g} s")


def mission_shot_config(mission, *, tier: str = "rf", at_s=None, beam: int = 0, overrides=(),
                        seed=None, root=None) -> MissionShot:
    """The tier input of one survey shot, as ``chirplidar run`` builds it (module docstring).

    ``mission``: a mission file (prepared with ``overrides`` and ``seed``) or a
    :class:`Prepared`; ``tier``: a registered tier (rf, baseband, link); ``at_s``: mission-clock time [s] (default: the
    first shot whose beam hits the terrain); ``beam``: beam index; ``root``: the SeedSequence
    whose child c seeds chunk c (default ``SeedSequence(config.seed)``, as the run).
    """
    if tier not in TIERS:
        raise ConfigError(f"--tier {tier}: a survey shot runs the tiers {', '.join(TIER_NAMES)}")
    prep = prepare_mission(mission, overrides=overrides, seed=seed)
    config, scene = prep.config, prep.scene
    if config.kind == "chirped" and config.system.modulation != "fm_chirp":
        raise ConfigError(f"{prep.source}: survey shots model FM chirps "
                          "(system.modulation = 'fm_chirp')")
    try:
        TIERS[tier].check(instrument_from_config(config))
    except ValueError as exc:
        raise ConfigError(f"{prep.source}: --tier {tier}: {exc}") from None
    geom, seq, i, k = locate_shot(prep, at_s=at_s, beam=beam, root=root)
    j = int(beam)
    instrument = instrument_from_config(config)
    if config.kind == "pulsed":
        returns, r_mean = _pulsed_shot_returns(prep, geom, seq, i, j)
        return MissionShot(instrument=instrument, returns=returns, tier=tier, seq=seq,
                           flat=i * geom.range_true_m.shape[1] + j,
                           geometry=_shot_geometry(scene, geom, i, j, k, r_mean))
    ptx_w = lab_budget(config).ptx_w
    f_d = shot_doppler_hz(config, scene, geom)
    if tier == "link":
        psig, r_mean = received(config, scene, geom, seq)[:2]
    else:
        fr = footprint_returns(config, scene, geom, seq)
        psig, r_mean = fr.psig_w, fr.range_m
    if not (np.isfinite(r_mean[i, j]) and psig[i, j] > 0):
        raise ConfigError(f"{prep.source}: beam {j} of the shot at t = {geom.t_s[i]:g} s "
                          "receives no power from its footprint")
    if tier == "link":
        ref = measure.window_reference_delay_s(config, geom, r_mean)[0]
        returns = measure.survey_returns(   # the mean return, with the run's range gate
            config, float(r_mean[i, j]), float(psig[i, j]) / ptx_w,
            reference_delay_s=None if ref is None else float(ref[i, j]),
            doppler_hz=float(f_d[i, j]))
    else:
        returns = measure.rf_shot_returns(config, instrument, ptx_w, geom, fr, i, j, f_d)
    return MissionShot(instrument=instrument, returns=returns, tier=tier, seq=seq,
                       flat=i * geom.range_true_m.shape[1] + j,
                       geometry=_shot_geometry(scene, geom, i, j, k, r_mean))


def _shot_geometry(scene, geom, i: int, j: int, k: int, r_mean) -> dict:
    """The shot's :data:`GEOMETRY_KEYS`."""
    code = int(geom.material[i, j])
    xyz = geom.hit_xyz_m[i, j]
    return {
        "t_s": float(geom.t_s[i]), "beam": j, "shot_index": int(k),
        "range_m": float(geom.range_true_m[i, j]), "footprint_range_m": float(r_mean[i, j]),
        "x_m": float(xyz[0]), "y_m": float(xyz[1]), "surface_height_m": float(xyz[2]),
        "surface": str(scene.terrain.material_names[code]),
        "incidence_deg": float(np.degrees(geom.incidence_rad[i, j])),
        "off_nadir_deg": float(np.degrees(geom.off_nadir_rad[i, j])),
        "platform_height_m": float(geom.platform_xyh[i, 2]),
    }


def _pulsed_shot_returns(prep, geom, seq, i: int, j: int):
    """A pulsed instrument's returns of shot ``i``, beam ``j``, as its run builds them
    (``measure_pulsed``: the window centred on the shot's own range), and the (n, b) mean
    ranges."""
    from ..channel.footprint import footprint_transmission
    from .measure_pulsed import background_power_per_shot_w, pulsed_batch_returns
    from .preflight import check_pulsed_survey

    config = prep.config
    check_pulsed_survey(config, prep.source)
    transmission, r_mean, _, frac, _ = footprint_transmission(config, prep.scene, geom, seq)
    if not (np.isfinite(r_mean[i, j]) and transmission[i, j] > 0):
        raise ConfigError(f"{prep.source}: beam {j} of the shot at t = {geom.t_s[i]:g} s "
                          "receives no energy from its footprint")
    background = background_power_per_shot_w(config, prep.scene, geom)
    flat = np.array([i * transmission.shape[1] + j])
    returns = pulsed_batch_returns(config, geom, transmission, r_mean, frac, background, flat)
    e = returns.echoes   # one shot's echoes as (k,): shared by every record of a --batch
    one = Echoes(e.delay_offset_s[0], e.power_weight[0], e.phase_rad[0])
    return dataclasses.replace(returns, echoes=one), r_mean


def simulate_mission_shot(mission, *, tier: str = "rf", at_s=None, beam: int = 0, overrides=(),
                          seed=None, root=None, rng=None, batch: int = 1,
                          keep_spectrum: bool = False) -> dict:
    """Run one survey shot through ``tier`` (see :func:`mission_shot_config` for the arguments).

    Returns the tier's raw outputs (arrays over ``batch`` records of the same footprint, Table
    4.10 names, ``flags``, ``tier``, ``f_beat_hz``, ``spectrum`` when asked) plus ``geometry``
    (:data:`GEOMETRY_KEYS`) and ``mission_geometry = True``. The tier draws from ``rng`` when
    given, else from the shot's own stream (:meth:`MissionShot.rng`): with ``batch = 1`` the rf
    tier's result is then the run's for that shot (same configuration, echoes and stream).
    """
    shot = mission_shot_config(mission, tier=tier, at_s=at_s, beam=beam, overrides=overrides,
                               seed=seed, root=root)
    returns = dataclasses.replace(shot.returns, batch=int(batch))   # records of one footprint
    raw = dict(TIERS[tier].simulate(shot.instrument, returns,
                                    shot.rng() if rng is None else rng,
                                    keep_spectrum=keep_spectrum))
    raw["geometry"] = shot.geometry
    raw["mission_geometry"] = True
    return raw
