"""Command line ``chirplidar``: ``shot``, ``sweep``, ``run``, ``coverage``, ``view``, ``study``,
``compare``, ``plan``, ``passes``, ``bench`` and ``sensitivity``.

Exit codes: 0 success, 1 a run finished but a requested product could not be made (e.g. no
spectrum to plot), or ``run`` stopped by another fault (e.g. its Dask scheduler lost), 2 bad input
(configuration error, unknown name, bad option, an unreadable input or unwritable output folder),
74 a file could not be written (disk full, permission denied, I/O error), 130 interrupted.
Configuration errors and faults are printed to stderr in one line, without a traceback
(``CHIRPLIDAR_DEBUG=1`` prints it too).

JSON output has no infinities: a non-finite number is written as ``null``. For the dB outputs
(dBm, dBm/Hz, dB) ``null`` means -inf dB, i.e. zero power (e.g. ``Psig`` with no return).

The parser is built by :func:`build_parser` (the documentation's command reference is generated
from it); each command lives in a ``commands_*`` module by group and imports the simulator only
when it runs, so ``chirplidar --help`` starts fast.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path
from typing import Sequence

from . import commands_bench, commands_compare, commands_lab, commands_planning, commands_survey
from .common import JSON_NOTE, SURVEY_TIERS, TIERS, UsageError, fix_mission_after_set

__all__ = ["build_parser", "main", "UsageError", "TIERS", "SURVEY_TIERS", "DEBUG_ENV", "EXIT_IO"]


def build_parser() -> argparse.ArgumentParser:
    """The ``chirplidar`` parser with every command (in the order ``--help`` lists them)."""
    parser = argparse.ArgumentParser(
        prog="chirplidar",
        description="Simulator for FM-chirped lidar with self-chirped homodyne detection.",
        epilog=JSON_NOTE)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in (commands_lab.add_shot_parser, commands_lab.add_sweep_parser,
                commands_survey.add_run_parser, commands_survey.add_coverage_parser,
                commands_survey.add_view_parser, commands_planning.add_plan_parser,
                commands_survey.add_study_parser, commands_compare.add_compare_parser,
                commands_bench.add_bench_parser,
                commands_planning.add_passes_parser, commands_lab.add_sensitivity_parser):
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command in ("shot", "sweep", "study", "run", "compare"):
            fix_mission_after_set(args.subparser, args)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)

    from ..config import ConfigError

    def show_warning(message, category, filename, lineno, file=None, line=None):
        # Simulator warnings (e.g. detector saturation) as one readable line, no source excerpt.
        print(f"chirplidar {args.command}: warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return int(args.func(args))
    except ConfigError as exc:
        print(f"chirplidar {args.command}: {exc}", file=sys.stderr)
        return 2
    except UsageError as exc:
        print(f"chirplidar {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        hint = ""
        if args.command == "run" and not getattr(args, "dry_run", False):
            from ..mission.manifest import chunk_dir_for
            from ..mission.runner import default_output

            chunks = chunk_dir_for(Path(args.out) if args.out else default_output(args.mission))
            if chunks.is_dir():
                hint = (f"; the finished chunks are kept in {chunks}: run the same command "
                        "with --resume to finish")
        print(f"chirplidar {args.command}: interrupted{hint}", file=sys.stderr)
        return 130
    except Exception as exc:   # faults in one line; bugs keep their traceback
        fault = _fault_line(args.command, exc)
        if fault is None:
            raise
        if _debug():
            import traceback

            traceback.print_exc()
        print(f"chirplidar {args.command}: {fault[0]}", file=sys.stderr)
        return fault[1]


#: Environment variable: print the traceback of an error that is otherwise shown in one line.
DEBUG_ENV = "CHIRPLIDAR_DEBUG"
#: Exit code of a file-system fault (disk full, permission denied, I/O error): EX_IOERR.
EXIT_IO = 74


def _debug() -> bool:
    return os.environ.get(DEBUG_ENV, "").strip() not in ("", "0")


def _fault_line(command: str, exc: Exception) -> tuple[str, int] | None:
    """(one line, exit code) for an error that is not a bug of the command: a run's fault
    (``runner.RunError``: its own line and code), an OS error of the file system (its file and
    reason, :data:`EXIT_IO`); in ``shot`` and ``sweep`` a ValueError of the physics (a
    configuration it cannot simulate, exit 2); in ``run``, any other error too (what failed,
    exit code 1).
    None: let it raise (traceback)."""
    runner = sys.modules.get("chirplidar.mission.runner")
    if runner is not None and isinstance(exc, getattr(runner, "RunError", ())):
        return str(exc), exc.exit_code
    if isinstance(exc, OSError) and isinstance(exc.errno, int) and exc.errno > 0 \
            and exc.filename is not None:
        return f"{exc.filename}: {os.strerror(exc.errno).lower()}", EXIT_IO
    if command in ("shot", "sweep") and isinstance(exc, ValueError):
        # the physics refuses a configuration it cannot simulate (e.g. a phase screen coarser
        # than r0): the user's input, in one line
        text = (str(exc).strip().splitlines() or [""])[0]
        return f"cannot simulate this configuration: {text}", 2
    if command in ("run", "compare"):
        text = (str(exc).strip().splitlines() or [""])[0]
        what = type(exc).__name__ + (f": {text}" if text else "")
        return f"failed: {what} ({DEBUG_ENV}=1 prints the traceback)", 1
    return None
