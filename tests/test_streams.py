"""The registry of named random streams (chirplidar.streams)."""

from __future__ import annotations

import numpy as np
import pytest

from chirplidar import streams
from chirplidar.config import models_survey


def test_stream_limits_are_the_configurations():
    # The indexed key ranges are sized for the limits the configuration enforces.
    assert streams.MAX_BEAMS == models_survey.MAX_BEAMS
    assert streams.MAX_CHUNK_SHOTS == models_survey.MAX_CHUNK_SHOTS


@pytest.mark.parametrize("name, indices, legacy_key", [
    # The spawn keys the streams had before the registry (mission/measure.py and
    # mission/survey.py at 7ef52a3: STREAM_JITTER = 1, STREAM_EFFECTS + beam, STREAM_NOISE = 200,
    # STREAM_BASEBAND + batch, (STREAM_SUBRAY_SPECKLE, beam, sub-ray), STREAM_FADING = 900_000,
    # STREAM_SIDEBAND = 900_001, STREAM_RF + flat; effect_rng: 1000 + the effect's index).
    ("jitter", (), (1,)),
    ("beam_effects", (3,), (103,)),
    ("link_noise", (), (200,)),
    ("baseband_batch", (7,), (307,)),
    ("subray_speckle", (2, 5), (400, 2, 5)),
    ("link_fading", (), (900_000,)),
    ("doppler_sideband", (), (900_001,)),
    ("rf_shot", (42,), (1_000_042,)),
    ("effect.speckle", (), (1001,)),
])
def test_named_streams_keep_their_spawn_keys(name, indices, legacy_key):
    # Same seed, same file as before the registry: each name maps to its old spawn key.
    seq = np.random.SeedSequence(2026).spawn(3)[1]
    got = streams.stream(seq, name, *indices).random(4)
    old = np.random.SeedSequence(entropy=seq.entropy, spawn_key=tuple(seq.spawn_key) + legacy_key)
    assert np.array_equal(got, np.random.default_rng(old).random(4))


def test_child_stream_does_not_consume_its_parent():
    rng = np.random.default_rng(5)
    state = rng.bit_generator.state
    streams.child_stream(rng, "effect.phase_noise").random(3)
    assert rng.bit_generator.state == state


def test_bad_names_and_indices_are_refused():
    seq = np.random.SeedSequence(1)
    with pytest.raises(KeyError, match="unknown random stream 'link_nosie'"):
        streams.stream(seq, "link_nosie")
    with pytest.raises(ValueError, match="takes an index"):
        streams.stream(seq, "rf_shot")
    with pytest.raises(ValueError):
        streams.stream(seq, "beam_effects", streams.MAX_BEAMS)   # past its key range


def test_overlapping_streams_are_refused_at_import():
    # Two streams of one spawn-key length whose ranges meet could draw the same numbers.
    clash = {"a": streams.Stream(300, "a", max_index=200), "b": streams.Stream(400, "b")}
    with pytest.raises(ImportError, match="overlap"):
        streams.check_disjoint(clash)
    apart = {"a": streams.Stream(300, "a", max_index=99), "b": streams.Stream(400, "b"),
             "c": streams.Stream(400, "c", extra=2)}     # another key length: no clash
    streams.check_disjoint(apart)
