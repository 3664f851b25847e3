"""The parameter grid of a mission study (:mod:`chirplidar.analysis.study`): the ``--vary`` specs,
the values they stand for, their TOML literals, and the units and dimension names of the keys.

``--vary KEY=START:STOP:N`` is N >= 2 values from START to STOP, evenly spaced (add ``:log`` for
geometric spacing, ``:lin`` is the default); integers when START and STOP are written as integers
and every value is one. ``--vary KEY=V1,V2,...`` lists the values, each read as ``--set`` reads a
value (a TOML literal, else a bare string: ``snow,blue_ice``); commas inside ``[...]`` or quotes do
not split (``beams.off_nadir_deg=[0.0],[15.0]``). KEY is any key ``--set`` accepts (thesis names
too, and ``scene.<scene key>``). At most two keys, each once; a key may not also be in ``--set``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np

from ..config.loader import ConfigError, is_known_key, resolve_key, tomllib, unknown_key_message

# Key suffix -> (CF units, axis-label units); longest suffix first.
_SUFFIX_UNITS: tuple[tuple[str, str, str], ...] = (
    ("_m_minus_2_3", "m-2/3", "m$^{-2/3}$"),
    ("_a_per_rthz", "A Hz-1/2", "A/$\\sqrt{Hz}$"),
    ("_v_per_rthz", "V Hz-1/2", "V/$\\sqrt{Hz}$"),
    ("_w_per_rthz", "W Hz-1/2", "W/$\\sqrt{Hz}$"),
    ("_hz_per_s", "Hz s-1", "Hz/s"),
    ("_per_m", "m-1", "1/m"),
    ("_rad_rms", "rad", "rad rms"),
    ("_deg_s", "degree s-1", "deg/s"),
    ("_mps", "m s-1", "m/s"),
    ("_dbm", "dBm", "dBm"),
    ("_db", "dB", "dB"),
    ("_deg", "degree", "deg"),
    ("_rad", "rad", "rad"),
    ("_hz", "Hz", "Hz"),
    ("_ohm", "ohm", "ohm"),
    ("_m2", "m2", "m$^2$"),
    ("_m", "m", "m"),
    ("_s", "s", "s"),
    ("_w", "W", "W"),
    ("_v", "V", "V"),
    ("_a", "A", "A"),
    ("_k", "K", "K"),
    ("_f", "F", "F"),
)


def key_units(key: str) -> tuple[str, str]:
    """(CF units, axis-label units) of a mission key from its SI suffix (``_m``, ``_deg``,
    ``_w``, ``_mps``, ``_db``, ...); ``("1", "")`` for a key without one."""
    leaf = resolve_key(key).rsplit(".", 1)[-1].lower()
    for suffix, cf, label in _SUFFIX_UNITS:
        if leaf.endswith(suffix):
            return cf, label
    return "1", ""


def dim_name(mission_key: str) -> str:
    """NetCDF-safe dimension name of a resolved mission key (``platform.uav.altitude_m`` ->
    ``platform_uav_altitude_m``)."""
    name = re.sub(r"[^0-9A-Za-z_]", "_", mission_key)
    return name if name[:1].isalpha() else f"v_{name}"


def toml_literal(value) -> str:
    """``value`` as the TOML literal that :func:`chirplidar.config.parse_set` reads back equal:
    the override text of a point (``key=<literal>``)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        f = float(value)
        if math.isnan(f):
            return "nan"
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        return repr(f)
    if isinstance(value, str):
        return json.dumps(value)   # a JSON string is a valid TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    raise ConfigError(f"cannot use the value {value!r} ({type(value).__name__}) in a study")


def _split_top(text: str, sep: str) -> list[str]:
    """``text`` split at ``sep`` outside brackets and quotes."""
    parts, depth, quote, cur = [], 0, None, []
    for ch in text:
        if quote:
            if ch == quote:
                quote = None
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == sep and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


def _literal(raw: str):
    """A value as ``--set`` reads it: a TOML literal, else the bare text as a string. TOML
    dates and times stay text (the configuration holds them as strings)."""
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw
    if not _plain(value):
        return raw
    return value


def _plain(value) -> bool:
    if isinstance(value, list):
        return all(_plain(v) for v in value)
    return isinstance(value, (bool, int, float, str))


def _number(raw: str, spec: str, what: str):
    value = _literal(raw)
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ConfigError(f"--vary {spec}: {what} {raw.strip()!r} is not a finite number "
                          "(expected KEY=START:STOP:N[:log] or KEY=V1,V2,...)")
    return value


@dataclass(frozen=True)
class VaryAxis:
    """One varied key: ``key`` as given, ``mission_key`` resolved (thesis names translated),
    its ``values`` (Python scalars or lists, as ``--set`` would read them), ``spacing``
    (``lin``, ``log`` or ``list``) and the ``spec`` text."""

    spec: str
    key: str
    mission_key: str
    values: tuple
    spacing: str

    @property
    def dim(self) -> str:
        return dim_name(self.mission_key)


def parse_vary(spec: str) -> VaryAxis:
    """Parse ``KEY=START:STOP:N[:log|:lin]`` or ``KEY=V1,V2,...`` (this module's docstring);
    ConfigError naming the spec for an unknown key, a malformed range, N < 2, or a repeated
    value."""
    if not isinstance(spec, str) or "=" not in spec:
        raise ConfigError(f"--vary {spec!r}: expected KEY=START:STOP:N[:log] or KEY=V1,V2,...")
    key, raw = (s.strip() for s in spec.split("=", 1))
    if not key:
        raise ConfigError(f"--vary {spec}: no key before '='")
    mission_key = resolve_key(key)
    if not is_known_key(mission_key):
        raise ConfigError(unknown_key_message(key, "--vary"))
    if not raw:
        raise ConfigError(f"--vary {spec}: no values after '=' (expected START:STOP:N[:log] "
                          "or V1,V2,...)")
    items = _split_top(raw, ",")
    fields = _split_top(raw, ":")
    quoted = raw[:1] in "\"'"
    if len(items) == 1 and len(fields) > 1 and not quoted:
        if len(fields) not in (3, 4):
            raise ConfigError(f"--vary {spec}: a range is START:STOP:N or START:STOP:N:log "
                              f"(got {len(fields)} fields)")
        spacing = fields[3].strip().lower() if len(fields) == 4 else "lin"
        if spacing not in ("lin", "log"):
            raise ConfigError(f"--vary {spec}: range spacing must be 'lin' or 'log', got "
                              f"{fields[3].strip()!r}")
        start = _number(fields[0], spec, "START")
        stop = _number(fields[1], spec, "STOP")
        n = _literal(fields[2])
        if isinstance(n, bool) or not isinstance(n, int):
            raise ConfigError(f"--vary {spec}: N {fields[2].strip()!r} must be an integer "
                              "number of values >= 2")
        if n < 2:
            raise ConfigError(f"--vary {spec}: a range needs N >= 2 values (got N = {n}); for "
                              "one value use --set")
        if start == stop:
            raise ConfigError(f"--vary {spec}: START and STOP are equal")
        if spacing == "log":
            if start <= 0 or stop <= 0:
                raise ConfigError(f"--vary {spec}: a log range needs START and STOP > 0")
            xs = np.geomspace(float(start), float(stop), n)
        else:
            xs = np.linspace(float(start), float(stop), n)
        whole = isinstance(start, int) and isinstance(stop, int) and np.all(xs == np.round(xs))
        values = tuple(int(np.rint(x)) for x in xs) if whole else tuple(float(x) for x in xs)
        if len(set(values)) != len(values):
            raise ConfigError(f"--vary {spec}: the range repeats values {list(values)}")
        return VaryAxis(spec, key, mission_key, values, spacing)
    if any(not it.strip() for it in items):
        raise ConfigError(f"--vary {spec}: an empty value in the list (expected V1,V2,...)")
    values = tuple(_literal(it) for it in items)
    if len(values) < 2:
        raise ConfigError(f"--vary {spec}: one value; give a list V1,V2,... or a range "
                          "START:STOP:N (use --set for a single value)")
    seen = set()
    for v in values:
        same = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) \
            else toml_literal(v)
        if same in seen:
            raise ConfigError(f"--vary {spec}: the value {toml_literal(v)} is listed twice")
        seen.add(same)
    return VaryAxis(spec, key, mission_key, values, "list")


def axis_coordinate(axis: VaryAxis) -> tuple[np.ndarray, str]:
    """(coordinate values, 'number' | 'string') of an axis: numbers as float64 (int64 when all
    are integers), one-element numeric lists as their number, anything else as its TOML text."""
    vals = axis.values
    def num(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if all(num(v) for v in vals):
        if all(isinstance(v, int) for v in vals):
            return np.array(vals, dtype=np.int64), "number"
        return np.array(vals, dtype=np.float64), "number"
    if all(isinstance(v, list) and len(v) == 1 and num(v[0]) for v in vals):
        return np.array([float(v[0]) for v in vals]), "number"
    return np.array([v if isinstance(v, str) else toml_literal(v) for v in vals], dtype=str), \
        "string"
