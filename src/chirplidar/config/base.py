"""The base of every configuration model, mission and scene alike.

:class:`StrictModel` refuses unknown keys, inf and NaN (a field that means something by inf says
so with ``allow_inf_nan=True``: only ``channel.extra_attenuation_db``,
``effects.turbulence.outer_scale_m`` and the scene's ``atmosphere.scale_height_m`` do), true/false
or text where a number belongs, numbers no SI quantity has, and dB values no instrument has.
:class:`FieldError` lets a check name the sub-key it is about.
"""

from __future__ import annotations

import math
import typing

from pydantic import BaseModel, ConfigDict, field_validator

#: Any key in dB beyond +-this is refused: 10^30 is no gain, loss or SNR an instrument has,
#: and powers that far apart overflow the single-precision records.
MAX_DB = 300.0
#: Any non-zero number of a configuration lies within these magnitudes (SI units): the
#: smallest quantities the simulator sees (Cn^2 ~ 1e-17 m^-2/3, NEP ~ 1e-12 W/rtHz) and their
#: squares are far inside; 1e-300 (a typo) underflows to 0 when squared.
SMALLEST_SI = 1e-100
LARGEST_SI = 1e100
#: dB keys whose losses MAX_DB does not bound, only their gains: a path loss may be anything (a
#: survey shot over specular water far off its glint loses 500 dB: no signal, as inf is).
ANY_LOSS_DB = frozenset({"extra_attenuation_db"})


def _accepts_bool(annotation) -> bool:
    if annotation is bool:
        return True
    return any(_accepts_bool(a) for a in typing.get_args(annotation))


def _only_numbers(annotation) -> bool:
    """Whether a field takes numbers only (int, float, optional or not): no text."""
    args = [a for a in (typing.get_args(annotation) or (annotation,)) if a is not type(None)]
    return bool(args) and all(a in (int, float) for a in args)


class FieldError(ValueError):
    """A check's complete message about one key: ``key`` is dotted and relative to the model
    being checked (``""``: the field itself). The message formatter prefixes the full key and
    adds nothing (the text says what was given)."""

    def __init__(self, key: str, text: str):
        super().__init__(f"{key}: {text}" if key else text)
        self.key = key
        self.text = text


class StrictModel(BaseModel):
    """The base of every configuration model (missions and scenes): unknown keys are errors,
    inf and NaN are refused (a field that means something by inf says so), and a number is
    never read from ``true``/``false`` (pydantic would read ``speed_mps = true`` as 1)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True,
                              allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_for_a_number(cls, value, info):
        annotation = cls.model_fields[info.field_name].annotation \
            if info.field_name in cls.model_fields else None
        if isinstance(value, bool) and annotation is not None and not _accepts_bool(annotation):
            raise ValueError("expected a number or text, not true or false")
        if isinstance(value, str) and annotation is not None and _only_numbers(annotation):
            raise ValueError("expected a number, not text (no quotes around numbers)")
        if isinstance(value, (int, float)) and not isinstance(value, bool) and \
                math.isfinite(value):
            loss_only = info.field_name in ANY_LOSS_DB   # any loss, but not any gain
            if info.field_name.endswith("_db") and (-value if loss_only else abs(value)) > MAX_DB:
                raise ValueError(f"{value:g} dB is a power ratio beyond 1e{MAX_DB / 10:.0f}: "
                                 "not a physical gain, loss or SNR (is it in linear units?)")
            if value != 0 and not SMALLEST_SI <= abs(value) <= LARGEST_SI:
                raise ValueError(f"{value:g} is outside {SMALLEST_SI:g}..{LARGEST_SI:g} in "
                                 "magnitude: no quantity in SI units is that small or large "
                                 "(its square under- or overflows)")
        return value
