"""Helpers shared by the command modules: tier choices, JSON output, usage errors, the options
common to ``shot`` and ``sweep``, output-file checks.

Nothing here imports the simulator at module level but the tier registry (numpy and the tiers'
declarations: what ``--tier`` offers): ``chirplidar --help`` builds every subparser, and each
command imports its heavy modules when it runs.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any, Sequence

from ..tiers.registry import TIER_NAMES
from ..tiers.registry import TIERS as TIER_REGISTRY

#: Tier names ``--tier`` accepts, from the tier registry: every tier for shot, sweep, run and
#: study; for ``sensitivity`` (thesis Fig. 5.7) the tiers that model all three of its receivers.
TIERS = TIER_NAMES
SURVEY_TIERS = TIER_NAMES
SENSITIVITY_TIERS = tuple(name for name, tier in TIER_REGISTRY.items()
                          if {"pin", "heterodyne", "homodyne"} <= tier.supports.receivers)


def tier_help(prefix: str) -> str:
    """``--tier`` help listing each tier's summary from the registry."""
    return prefix + "; ".join(f"{name} = {tier.summary}" for name, tier in TIER_REGISTRY.items())

JSON_NOTE = ("JSON has no infinities: non-finite numbers are written as null; for dB quantities "
             "null means -inf dB (zero power).")


class UsageError(Exception):
    """Bad command-line input detected after parsing (exit code 2)."""


def json_number(value: Any) -> Any:
    """A JSON-safe value: non-finite floats become None (null); numpy scalars become Python."""
    if value is None or isinstance(value, (bool, str, int)):
        return value
    try:
        f = float(value)
    except (TypeError, ValueError):
        return value
    return f if math.isfinite(f) else None


def dump_json(obj: Any) -> str:
    return json.dumps(obj, allow_nan=False, indent=None)


def fmt_value(value: float) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "nan"
    if math.isinf(value):
        return "-inf" if value < 0 else "inf"
    return f"{value:.6g}"


def stderr_lines(args):
    """A progress callback printing each line to stderr, or None with ``--json``."""
    return None if args.json else (lambda line: print(line, file=sys.stderr, flush=True))


def resolve_output_name(name: str, valid: Sequence[str], *, allow_x: str | None = None) -> str:
    """Table 4.10 name for ``name`` (``outputs.CNR`` -> ``SNR``); ``x`` or the varied key
    allowed."""
    from ..config import resolve_output

    if allow_x is not None and name in ("x", allow_x):
        return "x"
    resolved = resolve_output(name)
    if resolved not in valid:
        extra = f"x (the varied {allow_x}), " if allow_x else ""
        raise UsageError(f"unknown output name '{name}'; valid names: {extra}{', '.join(valid)} "
                         "(thesis 'outputs.NAME' and 'outputs.CNR' accepted)")
    return resolved


def load_config(args) -> Any:
    """The mission's configuration with ``--set``; ``--at-s`` and ``--beam`` (which pick a shot
    of a survey) are refused on a mission without a ``[survey]`` section."""
    from ..config import load_mission

    cfg = load_mission(args.mission, overrides_of(args))
    given = [o for o, v in (("--at-s", getattr(args, "at_s", None)),
                            ("--beam", getattr(args, "beam", None))) if v is not None]
    if given and cfg.survey is None:
        raise UsageError(f"{' and '.join(given)} pick a shot of a survey mission (a file with "
                         f"[scene], [platform], [attitude], [beams] and [survey]); "
                         f"{args.mission} has no [survey] section")
    return cfg


def fix_mission_after_set(parser: argparse.ArgumentParser, args) -> None:
    """``--set`` takes several KEY=VALUE; a MISSION written after it lands in args.set: move it."""
    if getattr(args, "mission", "") is None:
        if args.set and "=" not in args.set[-1]:
            args.mission = args.set.pop()
        else:
            parser.error("the following arguments are required: MISSION")


def check_cluster_args(args) -> None:
    """``--workers`` / ``--scheduler`` of ``run`` and ``study``."""
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler is not None:
        raise UsageError("--workers and --scheduler are exclusive: --workers N starts a local "
                         "cluster, --scheduler ADDRESS uses a running one")
    if args.scheduler is not None and not args.scheduler.strip():
        raise UsageError("--scheduler needs an address, e.g. tcp://127.0.0.1:8786")


def output_path(option: str, value, suffix: str, *, overwrite: bool | None) -> Path:
    """An output file named on the command line, checked before any work
    (:func:`chirplidar._checks.writable_file`) and, unless ``overwrite`` is None (a picture is
    replaced), refused when it exists without ``--overwrite``."""
    from .. import _checks

    try:
        path = _checks.writable_file(option, value, suffix)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if overwrite is not None and path.exists() and not overwrite:
        raise UsageError(f"{option} {path} exists: pass --overwrite to replace it "
                         "(nothing was computed)")
    return path


def add_common(p: argparse.ArgumentParser, *, mission_positional: bool = True) -> None:
    """MISSION, --set, --seed, --tier, --at-s and --beam of ``shot`` and ``sweep``."""
    if mission_positional:
        p.add_argument("mission", metavar="MISSION", nargs="?", default=None,
                       help="mission TOML file, e.g. missions/thesis_bench.toml")
    p.add_argument("--set", metavar="KEY=VALUE", action="extend", nargs="+", default=[],
                   help="override a mission key (thesis names accepted: chrp.F2=300e6, "
                        "sys.rsel=PIN, atm.Pattn=40); repeatable")
    add_instrument_option(p)
    p.add_argument("--seed", type=int, default=None,
                   help="random seed (default: the mission's seed)")
    p.add_argument("--tier", choices=TIERS, default="rf",
                   help=tier_help("fidelity tier (default rf): "))
    p.add_argument("--at-s", type=float, default=None, metavar="T",
                   help="survey missions: evaluate the shot nearest to T seconds of the mission "
                        "clock (default: the first shot whose beam hits the terrain)")
    p.add_argument("--beam", type=int, default=None, metavar="K",
                   help="survey missions: evaluate beam K of the shot (default 0)")


def add_instrument_option(p: argparse.ArgumentParser) -> None:
    """``--instrument FILE``: fly another instrument file (``--set instrument=FILE``)."""
    p.add_argument("--instrument", metavar="FILE.toml", default=None,
                   help="fly this instrument file instead of the mission's own instrument "
                        "(e.g. instruments/glas.toml); the mission keeps its path and scene")


def overrides_of(args) -> list[str]:
    """``--set`` with ``--instrument`` as its ``instrument=`` override (a path made absolute:
    chunks are recomputed elsewhere)."""
    sets = list(args.set or [])
    if getattr(args, "instrument", None):
        sets.append(f"instrument={Path(args.instrument).resolve()}")
    return sets


def allow_negative_values(p: argparse.ArgumentParser) -> None:
    """Let "-224000,-2504000,..." (a --bounds in Greenland, XMIN negative) be a value, not an
    option: the matcher Python >= 3.13 uses; 3.11's accepts a lone negative number only."""
    p._negative_number_matcher = re.compile(r"-\.?\d")
