"""Named random streams: every random draw of a run comes from a child of its SeedSequence.

A stream is named, never numbered at its call site: ``stream(seq, "link_noise")``,
``stream(seq, "rf_shot", flat)``, ``stream(seq, "subray_speckle", beam, subray)``. The child's
spawn key is the parent's plus the stream's key (plus its indices), so a stream's draws depend on
the seed and its name only: enabling an effect, adding a beam or running chunks on other workers
leaves every other stream unchanged.

The keys are the integers the streams have always had (results files stay the same for a seed).
Indexed streams own the key range ``key .. key + max_index``; :data:`STREAMS` is checked at
import so that no two streams of one family and spawn-key length share a key. The two families
hang under different parents: the survey streams under a chunk's SeedSequence, the ``effect.*``
streams under a tier call's generator (whose keys, 1000-1004, lie inside the baseband batches'
range: a tier's generator is never a chunk's SeedSequence itself in a run).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Stream:
    """A named stream: spawn-key element ``key`` (+ the index for indexed streams, up to
    ``max_index``), ``extra`` further indices appended as they are (0: none)."""

    key: int
    summary: str
    max_index: int = 0
    extra: int = 0

    @property
    def arity(self) -> int:
        return 1 + self.extra


# Limits the indexed ranges are sized for (config.models refuses more: MAX_BEAMS,
# MAX_CHUNK_SHOTS; tests/test_streams.py checks the two agree).
MAX_BEAMS = 64
MAX_CHUNK_SHOTS = 1_000_000
BASEBAND_BATCH = 256  # shots per baseband call of a survey chunk

STREAMS: dict[str, Stream] = {
    # Children of a survey chunk's SeedSequence.
    "jitter": Stream(1, "pointing jitter of the chunk's shots"),
    "beam_effects": Stream(
        100, "each beam's channel-effect draws (index: beam)", max_index=MAX_BEAMS - 1
    ),
    "link_noise": Stream(200, "the link tier's Cramer-Rao draw of the measured beat"),
    "baseband_batch": Stream(
        300,
        "each baseband batch of a chunk (index: batch)",
        max_index=-(-MAX_CHUNK_SHOTS * MAX_BEAMS // BASEBAND_BATCH) - 1,
    ),
    "subray_speckle": Stream(400, "each (beam, sub-ray)'s speckle field", extra=2),
    "link_fading": Stream(900_000, "the link tier's carrier-phase fading"),
    "doppler_sideband": Stream(900_001, "which Doppler sideband the link tier's peak takes"),
    "rf_shot": Stream(
        1_000_000,
        "each rf shot-beam (index: shot x beams + beam)",
        max_index=MAX_CHUNK_SHOTS * MAX_BEAMS - 1,
    ),
    "pulsed_batch": Stream(
        100_000_000,
        "each pulsed-tier batch of a chunk (index: batch; a batch holds at least one shot-beam)",
        max_index=MAX_CHUNK_SHOTS * MAX_BEAMS - 1,
    ),
    # Children of a tier call's generator: one per channel effect (effects registry order).
    "effect.phase_noise": Stream(1000, "laser phase noise (Wiener)"),
    "effect.speckle": Stream(1001, "target speckle"),
    "effect.doppler": Stream(1002, "Doppler (draws nothing today)"),
    "effect.coupling": Stream(1003, "fiber coupling (draws nothing today)"),
    "effect.turbulence": Stream(1004, "turbulence phase screens"),
    # Children of the same generator for the [receiver]'s focal-plane field (channel.receiver).
    "effect.receiver_speckle": Stream(1005, "the receiver's pupil speckle fields"),
    "effect.receiver_turbulence": Stream(1006, "the receiver's pupil phase screens"),
}


def check_disjoint(streams: dict[str, Stream]) -> None:
    """No two streams of one spawn-key length may share a key. The effect streams are children
    of a tier call's generator, never of a chunk's: they are checked among themselves."""
    for group in (False, True):
        taken: list[tuple[int, int, int, str]] = []
        for name, s in streams.items():
            if name.startswith("effect.") != group:
                continue
            for lo, hi, arity, other in taken:
                if arity == s.arity and lo <= s.key + s.max_index and s.key <= hi:
                    raise ImportError(f"random streams {name!r} and {other!r} overlap")
            taken.append((s.key, s.key + s.max_index, s.arity, name))


check_disjoint(STREAMS)


def stream_seed(seq: np.random.SeedSequence, name: str, *indices: int) -> np.random.SeedSequence:
    """The SeedSequence of stream ``name`` (with its indices) under ``seq``."""
    try:
        s = STREAMS[name]
    except KeyError:
        raise KeyError(f"unknown random stream {name!r}; known: {', '.join(STREAMS)}") from None
    wanted = (1 if s.max_index else 0) + s.extra
    first, rest = (indices[0], indices[1:]) if s.max_index and indices else (0, indices)
    if len(indices) != wanted or not 0 <= first <= s.max_index:
        index = f"an index in 0..{s.max_index}" if s.max_index else "no index"
        raise ValueError(
            f"random stream {name!r} takes {index} and {s.extra} further indices; got {indices}"
        )
    key = (s.key + int(first),) + tuple(int(i) for i in rest)
    return np.random.SeedSequence(entropy=seq.entropy, spawn_key=tuple(seq.spawn_key) + key)


def stream(seq: np.random.SeedSequence, name: str, *indices: int) -> np.random.Generator:
    """A Generator on stream ``name`` of ``seq`` (see :data:`STREAMS`)."""
    return np.random.default_rng(stream_seed(seq, name, *indices))


def child_stream(rng: np.random.Generator, name: str, *indices: int) -> np.random.Generator:
    """Stream ``name`` under ``rng``'s SeedSequence (``rng`` itself is not consumed)."""
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):
        raise TypeError(f"random stream {name!r}: the generator was not seeded by a SeedSequence")
    return stream(seq, name, *indices)
