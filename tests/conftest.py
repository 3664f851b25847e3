from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "missions" / "thesis_bench.toml"
CH5 = ROOT / "missions" / "thesis_ch5_bench.toml"

# A small, fast configuration of the same physics (16 us record at 1.2 GS/s) for statistics.
SMALL = ["sims.T=16e-6", "chrp.Tchp=16e-6", "sims.Fs=1.2e9", "chrp.F2=250e6", "atm.dst=300",
         "COH.f_LO=2e8"]


@pytest.fixture
def bench_path():
    return BENCH


@pytest.fixture
def ch5_path():
    return CH5
