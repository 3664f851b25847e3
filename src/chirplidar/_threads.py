"""One BLAS thread inside the simulation kernels.

The kernels' matrix products are small or memory-bound (the baseband tier's per-record
coefficients times three functions of time, the DTFT kernel near a peak). OpenBLAS would start
its own threads for them; on a 2-core machine their spin-waits then compete with the numpy passes
and the FFT threads of the same shot: a thesis-bench baseband shot measured 187-375 us with
OpenBLAS's default 2 threads against 146-158 us with one (``bench --what tiers``). Parallelism
belongs to the processes of a run (``chirplidar run --workers``), not to BLAS.
"""

from __future__ import annotations

import threading

_LOCK = threading.Lock()
_CONTROLLER = None


def single_threaded_blas():
    """A context manager limiting every loaded BLAS library to one thread (threadpoolctl)."""
    global _CONTROLLER
    from threadpoolctl import ThreadpoolController

    with _LOCK:
        if _CONTROLLER is None:
            _CONTROLLER = ThreadpoolController()  # inspects the loaded libraries once (~8 ms)
    return _CONTROLLER.limit(limits=1, user_api="blas")
