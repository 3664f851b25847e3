"""``chirplidar bench --what startup``: wall time of ``chirplidar --help`` and of
``import chirplidar.units``, each in a fresh Python process.

A process is timed from its start to its exit (``time.perf_counter`` around ``subprocess.run``),
so the figure includes the interpreter's own start, which is timed too (``python -c pass``) as
the floor no command goes below. The three are run in turn, ``repeats`` rounds after one untimed
round (the OS file cache), and each figure is the median over the rounds: a shared machine's
drift affects them alike. The processes inherit this one's environment (``PYTHONPATH``
included), so they import the same chirplidar.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

#: The command line's goal for ``chirplidar --help`` [s].
HELP_GOAL_S = 0.5

#: Timed processes: result key -> Python code run with ``python -c``. ``help_s`` is what the
#: ``chirplidar`` console script runs.
PROGRAMS = {
    "help_s": "import sys; from chirplidar.cli import main; sys.exit(main(['--help']))",
    "import_units_s": "import chirplidar.units",
    "python_s": "pass",
}


def time_process(code: str) -> float:
    """Wall time [s] of ``python -c code`` from start to exit; its output is discarded."""
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"python -c {code!r} failed (exit {res.returncode}): "
                           f"{res.stderr.strip()}")
    return elapsed


def bench_startup(repeats: int = 11) -> dict[str, float | int]:
    """Median wall times [s] of the :data:`PROGRAMS` over ``repeats`` rounds, and ``repeats``."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    for code in PROGRAMS.values():
        time_process(code)   # untimed: the file cache
    times: dict[str, list[float]] = {key: [] for key in PROGRAMS}
    for _ in range(repeats):
        for key, code in PROGRAMS.items():
            times[key].append(time_process(code))
    return {**{key: statistics.median(t) for key, t in times.items()}, "repeats": repeats}


def format_startup(res: dict) -> str:
    return "\n".join([
        f"start-up wall time, fresh processes, median of {res['repeats']}:",
        f"  chirplidar --help         {res['help_s']:7.3f} s   (goal < {HELP_GOAL_S:g} s)",
        f"  import chirplidar.units   {res['import_units_s']:7.3f} s",
        f"  python -c pass            {res['python_s']:7.3f} s   (the interpreter alone)",
    ])
