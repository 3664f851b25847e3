"""The results file's schema: its variables, CF attributes, flag meanings and storage layout.

The per-shot results of a mission are a CF-1.8 trajectory dataset (built by
:func:`.dataset.build_dataset`, written by :mod:`.writer`, merged by :mod:`.merge`, read back by
:mod:`.read`).

Representation
--------------
CF-1.8 discrete sampling geometry, ``featureType = "trajectory"``, one trajectory per beam, in the
*multidimensional array representation* (CF-1.8 Appendix H.4.1): every per-shot variable has dims
``("trajectory", "obs")``; ``beam(trajectory)`` is the trajectory variable
(``cf_role = "trajectory_id"``). All beams fire on the same shot clock, so every trajectory has the
same length and there is no padding. ``time`` and ``delta_time`` are 2-D auxiliary coordinates (as
CF H.4.1 requires for trajectories), so beams may carry slightly different shot times.

Coordinates (``delta_time``, ``time``, ``latitude``, ``longitude``, ``x``, ``y``, ``beam``) are
xarray coordinates; xarray writes the CF ``coordinates`` attribute of every data variable from
them. ``x``/``y`` are polar-stereographic metres of the footprint; every ``(trajectory, obs)`` data
variable carries ``grid_mapping = "crs"``, and the scalar ``crs`` variable holds
``pyproj.CRS.from_epsg(epsg).to_cf()`` (``grid_mapping_name = "polar_stereographic"`` for
EPSG:3413 Greenland and EPSG:3031 Antarctica).

``time`` is kept numeric in memory (float64, ``units = "seconds since <epoch>"``, equal to
``delta_time``) and :func:`read_netcdf` does not decode it, so a written file reads back
identical: decoding float seconds to ``datetime64[ns]`` is not exact. ``xarray.decode_cf(ds)``
gives datetimes.

Missing values
--------------
Float variables are written with ``_FillValue = NaN``. CF allows a NaN fill value for floating
point data; a NaN range, height, power, frequency, SNR or position means "no value for this shot"
and the ``detected`` flag says why (below threshold, no surface in the beam). Flag variables
(``detected``, ``surface_type``, ``track``) and ``beam`` are integers with no fill value: every
shot has one. ``range_measured``, ``range_error``, ``h_li`` and ``h_li_sigma`` should be NaN
where ``detected != 1``; this module does not alter data to enforce it.

Mapping to thesis Table 4.10 (and the ``--json`` output of a shot)
------------------------------------------------------------------
================== ============== =========================================================
results variable   thesis name    relation
================== ============== =========================================================
range_measured     d_rx           identical (m)
range_error        d_error        identical, ``range_true - range_measured`` (m)
range_true         dst            configured / geometric target distance (input, not 4.10)
snr_db             SNR            identical (dB in the RBW, eq. 2.6.12)
received_power     Psig           ``received_power = 1e-3 * 10**(Psig / 10)`` (W; Psig dBm)
beat_frequency     f_beat_hz      ``--json`` key (Hz), not in Table 4.10
================== ============== =========================================================

The other Table 4.10 outputs (Pchrp, Ptx, Ne, Ns, Nt, d_offset, d_lo, d_hi, d_3dB, d_res, Crx,
Navg) describe the instrument or the spectrum of one shot and are not stored per shot.

ICESat-2 names used: ``delta_time``, ``latitude``, ``longitude``, ``h_li`` (ATL06 land-ice height
above the WGS-84 ellipsoid; ``h_li_true`` is the same surface without measurement error),
``h_li_sigma`` (ATL06's expected error of ``h_li``; here the Cramer-Rao spread of one shot).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import xarray as xr

TRAJECTORY_DIM = "trajectory"
OBS_DIM = "obs"
GRID_MAPPING_NAME = "crs"
CONVENTIONS = "CF-1.8"
FEATURE_TYPE = "trajectory"

# detected: why a shot has (no) return.
# 3: the return lies outside the range gate (survey.range_window_m, or without one the ranges
# whose beat lies in the processed band with the chirps overlapping): the instrument does not
# look there, its beat would alias or leave the band; 4: a resolved Doppler shift displaces the
# beat line by more than the range resolution and nothing compensates it; 5: the return's delay
# lies outside [tau_ref, tau_ref + T) of the reference delay (T the chirp period), so the range
# read from its beat is off by a multiple of c T / 2n (whatever its SNR).
DETECTED_FLAG_VALUES = np.array([0, 1, 2, 3, 4, 5], dtype=np.int8)
DETECTED_FLAG_MEANINGS = ("below_detection_threshold detected no_surface_in_beam "
                          "outside_range_gate doppler_displaced range_ambiguous")


@dataclass(frozen=True)
class VarSpec:
    """One row of the per-shot schema."""

    name: str
    dtype: str                  # "float64", "int8", "int16", "int32"
    units: str
    long_name: str
    standard_name: str | None = None
    icesat2_name: str | None = None  # ICESat-2 product name where the variable follows one
    thesis_name: str | None = None   # thesis Table 4.10 (or --json) name it maps to
    coordinate: bool = False         # an xarray coordinate (CF auxiliary coordinate)
    nan_allowed: bool = True         # float variables: NaN = no value for this shot


# The schema: one table for every per-shot variable (all have dims (trajectory, obs) except
# ``beam``, the trajectory variable, which has dims (trajectory,)).
SCHEMA: tuple[VarSpec, ...] = (
    VarSpec("beam", "int32", "1", "beam (trajectory) identifier", coordinate=True),
    VarSpec("delta_time", "float64", "s", "elapsed time since the mission epoch", None,
            "delta_time", coordinate=True, nan_allowed=False),
    VarSpec("time", "float64", "seconds since <epoch>", "time of the shot", "time",
            coordinate=True, nan_allowed=False),
    VarSpec("latitude", "float64", "degrees_north", "latitude of the footprint centre",
            "latitude", "latitude", coordinate=True),
    VarSpec("longitude", "float64", "degrees_east", "longitude of the footprint centre",
            "longitude", "longitude", coordinate=True),
    VarSpec("x", "float64", "m", "projected x of the footprint centre",
            "projection_x_coordinate", coordinate=True),
    VarSpec("y", "float64", "m", "projected y of the footprint centre",
            "projection_y_coordinate", coordinate=True),
    VarSpec("platform_x", "float64", "m", "projected x of the platform"),
    VarSpec("platform_y", "float64", "m", "projected y of the platform"),
    VarSpec("platform_altitude", "float64", "m",
            "platform height above the WGS-84 ellipsoid"),
    VarSpec("track", "int32", "1", "survey line (UAV, aircraft) or pass (satellite) of the "
            "shot; -1 in turns and transits between lines"),
    VarSpec("off_nadir_angle", "float64", "radian", "beam off-nadir pointing angle"),
    VarSpec("azimuth_angle", "float64", "radian",
            "beam pointing azimuth, clockwise from true north"),
    VarSpec("incidence_angle", "float64", "radian",
            "angle between the beam and the local surface normal"),
    VarSpec("range_true", "float64", "m", "true platform-to-surface range along the beam",
            thesis_name="dst"),
    VarSpec("range_measured", "float64", "m", "measured range (detected target distance)",
            thesis_name="d_rx"),
    VarSpec("range_error", "float64", "m", "range error range_true - range_measured",
            thesis_name="d_error"),
    VarSpec("h_li_true", "float64", "m",
            "true surface height above the WGS-84 ellipsoid at the footprint",
            "height_above_reference_ellipsoid"),
    VarSpec("h_li", "float64", "m", "measured surface height above the WGS-84 ellipsoid",
            "height_above_reference_ellipsoid", "h_li"),
    VarSpec("h_li_sigma", "float64", "m",
            "predicted 1-sigma precision of h_li: Cramer-Rao bound of the beat frequency at the "
            "shot's SNR and 3 dB width (pulsed instruments: of the pulse's arrival time)",
            icesat2_name="h_li_sigma"),
    VarSpec("snr_db", "float64", "dB", "signal-to-noise ratio in the resolution bandwidth",
            thesis_name="SNR"),
    VarSpec("received_power", "float64", "W", "received optical signal power (pulsed "
            "instruments: the received pulse's peak power)",
            thesis_name="Psig (dBm)"),
    VarSpec("beat_frequency", "float64", "Hz", "detected beat frequency",
            thesis_name="f_beat_hz"),
    VarSpec("beat_width", "float64", "Hz", "3 dB width of the detected beat peak",
            thesis_name="d_3dB (in Hz)"),
    VarSpec("pulse_width", "float64", "s",
            "RMS width of the received pulse waveform (pulsed instruments)"),
    VarSpec("footprint_diameter", "float64", "m", "laser footprint diameter on the surface"),
    VarSpec("detected", "int8", "1", "surface return detection flag", "status_flag"),
    VarSpec("surface_type", "int16", "1", "surface material at the footprint"),
)
SCHEMA_BY_NAME: dict[str, VarSpec] = {s.name: s for s in SCHEMA}
#: Variables an instrument kind does not measure: all fill values (NaN) in its files.
NOT_MEASURED_BY: dict[str, tuple[str, ...]] = {
    "chirped": ("pulse_width",),
    "pulsed": ("beat_frequency", "beat_width"),
}
#: Bytes of one shot of one beam held in memory (every variable as float64): the bound of a
#: chunk's memory and of a results file before compression.
BYTES_PER_BEAM_SHOT = 8 * len(SCHEMA)
#: Variables computed from others (``time`` from ``delta_time``), never passed in.
DERIVED_VARIABLES = frozenset({"time"})
#: zlib level of the compressed (float) variables of every results file (with the shuffle
#: filter). Level 1: a survey's float64 columns compress to within 2 % of level 4's size in
#: three quarters of its time (issue 19, 100 000 shots of the one-hour flight: 7.34 MB in
#: 201 ms against 7.23 MB in 272 ms; uncompressed 14.1 MB).
COMPRESSION_LEVEL = 1


def crs_attributes(epsg) -> dict:
    """CF grid-mapping attributes of a projected EPSG code (pyproj's ``to_cf`` plus GDAL's
    ``spatial_ref``); ValueError for an unknown or unprojected code."""
    if isinstance(epsg, (bool, np.bool_)) or not isinstance(epsg, (int, np.integer)):
        raise ValueError(f"epsg must be an integer EPSG code, got {epsg!r}")
    from pyproj import CRS
    from pyproj.exceptions import CRSError
    try:
        crs = CRS.from_epsg(int(epsg))
    except CRSError as exc:
        raise ValueError(f"epsg: unknown EPSG code {epsg!r}: {exc}") from None
    if not crs.is_projected:
        raise ValueError(f"epsg must be a projected CRS (e.g. 3413, 3031), got EPSG:{epsg}")
    attrs = dict(crs.to_cf())
    attrs["spatial_ref"] = attrs["crs_wkt"]  # GDAL reads this name
    attrs["epsg_code"] = f"EPSG:{int(epsg)}"
    attrs["long_name"] = f"coordinate reference system EPSG:{int(epsg)}"
    return attrs


def flag_meaning(name: str) -> str:
    """A material name as one CF ``flag_meanings`` word (blank-separated list)."""
    return re.sub(r"[^0-9A-Za-z_.+\-@]+", "_", name.strip())


def variable_attributes(spec: VarSpec, epoch_iso: str, materials: dict[int, str]) -> dict:
    """The CF attributes of schema variable ``spec``: long name and units, the time units of
    ``epoch_iso``, standard name, trajectory role and flag values and meanings (``materials``:
    surface type code -> material name)."""
    attrs: dict = {"long_name": spec.long_name, "units": spec.units}
    if spec.name == "time":
        attrs["units"] = f"seconds since {epoch_iso}"
        attrs["calendar"] = "standard"
        attrs["axis"] = "T"
    if spec.name == "delta_time":
        attrs["long_name"] = f"elapsed seconds since the mission epoch {epoch_iso}"
    if spec.standard_name:
        attrs["standard_name"] = spec.standard_name
    if spec.name == "beam":
        attrs["cf_role"] = "trajectory_id"
    if spec.name == "detected":
        attrs["flag_values"] = DETECTED_FLAG_VALUES.copy()
        attrs["flag_meanings"] = DETECTED_FLAG_MEANINGS
    if spec.name == "surface_type":
        keys = sorted(materials)
        attrs["flag_values"] = np.array(keys, dtype=np.int16)
        attrs["flag_meanings"] = " ".join(flag_meaning(materials[k]) for k in keys)
    return attrs


def check_dataset(ds: xr.Dataset) -> None:
    """Raise ValueError unless every variable has ``units`` and ``long_name`` and the required
    global attributes are present. The grid-mapping variable (it holds no data) needs no units."""
    for name, var in ds.variables.items():
        if "long_name" not in var.attrs:
            raise ValueError(f"variable {name!r} has no long_name")
        if "grid_mapping_name" in var.attrs:  # grid mapping container: no data, no units
            continue
        if "units" not in var.attrs and "units" not in var.encoding:
            raise ValueError(f"variable {name!r} has no units")
        gm = var.attrs.get("grid_mapping")
        if gm is not None and gm not in ds.variables:
            raise ValueError(f"variable {name!r}: grid_mapping {gm!r} is not in the dataset")
    for key in ("Conventions", "featureType", "title", "source", "history", "date_created",
                "configuration", "seed"):
        if key not in ds.attrs:
            raise ValueError(f"global attribute {key!r} is missing")
    if not any(v.attrs.get("cf_role") == "trajectory_id" for v in ds.variables.values()):
        raise ValueError("no variable with cf_role = 'trajectory_id'")


# --------------------------------------------------------------------------------------------
# storage layout (compression and HDF5 chunks), shared by the writer and the merge


def is_compressed(dtype, ndim: int, size: int) -> bool:
    """Whether a results variable is stored with zlib (:data:`COMPRESSION_LEVEL`): non-empty
    float arrays."""
    return bool(np.issubdtype(dtype, np.floating) and ndim and size)


def chunk_sizes(dims, shape, obs_chunk: int | None, *, obs_unlimited: bool = False):
    """HDF5 chunk shape of a compressed variable: ``obs_chunk`` observations (at most all of
    them, unless ``obs`` is unlimited) by the full other dimensions, or None (netCDF's default
    chunking) without ``obs_chunk`` or an ``obs`` dimension."""
    if obs_chunk is None or OBS_DIM not in dims:
        return None
    return tuple((int(obs_chunk) if obs_unlimited else min(int(obs_chunk), n))
                 if d == OBS_DIM else n for d, n in zip(dims, shape))


def check_obs_chunk(obs_chunk) -> int | None:
    """``obs_chunk`` (observations per HDF5 chunk) as an int, or None; ValueError otherwise."""
    if obs_chunk is not None and (isinstance(obs_chunk, (bool, np.bool_))
                                  or not isinstance(obs_chunk, (int, np.integer))
                                  or obs_chunk < 1):
        raise ValueError(f"obs_chunk must be a positive integer or None, got {obs_chunk!r}")
    return None if obs_chunk is None else int(obs_chunk)
