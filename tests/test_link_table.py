"""The link tier's survey table (``tiers.link_survey``): its range nodes lie on one lattice for
every chunk, so a run computes each node once, and interpolating it stays within 0.001 dB of the
closed form evaluated at the shot's own range and attenuation."""

from __future__ import annotations

import numpy as np

from chirplidar.config import load_mission
from chirplidar.config.instrument import instrument_from_config
from chirplidar.mission.measure import survey_path
from chirplidar.tiers import link_survey
from chirplidar.tiers.link_survey import interp_table, link_table, node_returns, range_nodes
from chirplidar.tiers.link import simulate_link
from conftest import ROOT


def test_range_nodes_are_shared_by_overlapping_chunks():
    """Two chunks' range spans that overlap share their nodes where they overlap (one lattice,
    r_k = exp(0.01 k); a span of more than 32 steps takes every s-th node, k a multiple of s),
    at most 34 nodes, covering each span."""
    a, b = range_nodes(118.0, 161.0), range_nodes(140.0, 205.0)   # strides 1 and 2
    assert a[0] <= 118.0 and a[-1] >= 161.0 and b[0] <= 140.0 and b[-1] >= 205.0
    inside = b[(b >= a[0]) & (b <= a[-1])]
    assert inside.size >= 5 and np.all(np.isin(inside, a))      # the same floats
    wide = range_nodes(100.0, 600_000.0)
    assert wide.size <= 34 and wide[0] <= 100.0 and wide[-1] >= 600_000.0
    assert np.allclose(np.diff(np.log(a)), 0.01)


def test_table_interpolation_matches_the_closed_form_at_the_shot():
    """The demo's instrument: SNR interpolated from the lattice's nodes against simulate_link at
    40 random (range, attenuation) points of a chunk's span, within 0.001 dB (the nodes are 1 %
    apart in range: SNR in dB is smooth there)."""
    config = load_mission(ROOT / "missions" / "greenland_uav.toml")
    inst, path = instrument_from_config(config), survey_path(config)
    link_survey._NODES.clear()
    r_nodes, a_nodes, table, _, _ = link_table(inst, path, 118.0, 161.0, -5.0, 20.0, False)
    rng = np.random.default_rng(1)
    r = rng.uniform(118.0, 161.0, 40)
    a = rng.uniform(-5.0, 20.0, 40)
    got = interp_table(r_nodes, a_nodes, table, r, a)
    exact = [simulate_link(inst, node_returns(inst, path, float(ri), float(ai)),
                           np.random.default_rng(0))["SNR"][0] for ri, ai in zip(r, a)]
    assert np.max(np.abs(got - np.asarray(exact))) < 1e-3
