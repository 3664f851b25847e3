"""Generated terrain: flat and sloped test planes with closed-form ranges, and a synthetic ice
sheet (a Vialov flow-line profile with crevasses, sastrugi, melt ponds and rock outcrops, all
seeded by a ``numpy.random.Generator``).

Each surface comes as a heightfield ``(x_m, y_m, z_m, codes)`` (``*_heightfield``: what the scene
loader caches) and as a :class:`~chirplidar.geometry.terrain.Terrain` built from it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .terrain import MATERIAL_CODES, Terrain, material_code

__all__ = [
    "HEIGHTFIELD_GENERATORS",
    "SYNTHETIC_FEATURES",
    "flat_plane",
    "flat_plane_heightfield",
    "sloped_plane",
    "sloped_plane_heightfield",
    "synthetic_ice_sheet",
    "synthetic_ice_sheet_heightfield",
    "vialov_height",
]


def _extent(extent_m):
    try:
        x0, x1, y0, y1 = (float(v) for v in extent_m)
    except (TypeError, ValueError):
        raise ValueError(f"extent_m must be (x0, x1, y0, y1) in metres, got {extent_m!r}") from None
    if not all(np.isfinite([x0, x1, y0, y1])) or x1 <= x0 or y1 <= y0:
        raise ValueError(f"extent_m must be finite with x0 < x1 and y0 < y1, got {extent_m!r}")
    return x0, x1, y0, y1


def _grid(extent_m, resolution_m):
    x0, x1, y0, y1 = _extent(extent_m)
    res = float(resolution_m)
    if not np.isfinite(res) or res <= 0:
        raise ValueError(f"resolution_m must be > 0, got {resolution_m!r}")
    nx = int(np.ceil((x1 - x0) / res - 1e-9)) + 1
    ny = int(np.ceil((y1 - y0) / res - 1e-9)) + 1
    if nx * ny > 50_000_000:
        raise ValueError(f"resolution_m={res} gives {nx}x{ny} nodes (> 5e7); coarsen it")
    return np.linspace(x0, x1, max(nx, 2)), np.linspace(y0, y1, max(ny, 2))


def flat_plane_heightfield(height_m, extent_m, resolution_m, material: str = "snow"):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of ``flat_plane`` (``Terrain.from_heightfield``)."""
    h = float(height_m)
    if not np.isfinite(h):
        raise ValueError(f"height_m must be finite, got {height_m!r}")
    x, y = _grid(extent_m, resolution_m)
    z = np.full((y.size, x.size), h)
    return x, y, z, np.full(z.shape, material_code(material), np.int32)


def flat_plane(height_m, extent_m, resolution_m, material: str = "snow") -> Terrain:
    """Horizontal plane z = height_m over extent_m = (x0, x1, y0, y1), grid step resolution_m."""
    return Terrain.from_heightfield(
        *flat_plane_heightfield(height_m, extent_m, resolution_m, material)
    )


def sloped_plane_heightfield(
    slope_rad,
    azimuth_rad,
    height_m,
    extent_m,
    resolution_m,
    material: str = "snow",
    origin_m=(0.0, 0.0),
):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of ``sloped_plane``."""
    s, az, h = float(slope_rad), float(azimuth_rad), float(height_m)
    if not np.isfinite([s, az, h]).all() or not 0 <= s < np.pi / 2:
        raise ValueError(
            f"slope_rad must lie in [0, pi/2) and azimuth_rad, height_m be finite; "
            f"got {slope_rad!r}, {azimuth_rad!r}, {height_m!r}"
        )
    x, y = _grid(extent_m, resolution_m)
    xx, yy = np.meshgrid(x - origin_m[0], y - origin_m[1])
    z = h + np.tan(s) * (xx * np.cos(az) + yy * np.sin(az))
    return x, y, z, np.full(z.shape, material_code(material), np.int32)


def sloped_plane(
    slope_rad,
    azimuth_rad,
    height_m,
    extent_m,
    resolution_m,
    material: str = "snow",
    origin_m=(0.0, 0.0),
) -> Terrain:
    """Plane through (origin_m, height_m) rising at ``slope_rad`` towards ``azimuth_rad``.

    azimuth_rad is measured from +x towards +y (mathematical convention, not a compass bearing):
    z = height_m + tan(slope_rad) * ((x - x0) cos(az) + (y - y0) sin(az)).
    """
    return Terrain.from_heightfield(
        *sloped_plane_heightfield(
            slope_rad, azimuth_rad, height_m, extent_m, resolution_m, material, origin_m
        )
    )


# ---------------------------------------------------------------------- synthetic ice sheet
def vialov_height(x_m, divide_height_m, margin_distance_m, divide_x_m=0.0):
    """Vialov (1958) steady ice-sheet profile, as in Cuffey & Paterson (2010) eq. 8.34.

    h(x) = H [1 - (|x - x_d| / L)^(4/3)]^(3/8) for |x - x_d| <= L, else 0 (Glen n = 3, flat bed,
    uniform accumulation). H = divide_height_m, L = margin_distance_m, x_d = divide_x_m.
    """
    H = float(divide_height_m)
    L = float(margin_distance_m)
    if not (np.isfinite(H) and H > 0):
        raise ValueError(f"divide_height_m must be > 0, got {divide_height_m!r}")
    if not (np.isfinite(L) and L > 0):
        raise ValueError(f"margin distance must be > 0, got {margin_distance_m!r}")
    xi = np.clip(np.abs(np.asarray(x_m, dtype=np.float64) - divide_x_m) / L, 0.0, 1.0)
    return H * (1.0 - xi ** (4.0 / 3.0)) ** (3.0 / 8.0)


SYNTHETIC_FEATURES = ("crevasses", "sastrugi", "ponds", "outcrops")


def _smooth_noise(rng, shape, dx, corr_along_m, corr_across_m, azimuth_rad):
    """Zero-mean unit-rms Gaussian random field with an anisotropic Gaussian correlation.

    FFT filtering of white noise; correlation lengths corr_along_m (along azimuth) and
    corr_across_m (across), grid step dx (m).
    """
    ny, nx = shape
    white = rng.standard_normal(shape)
    kx = 2 * np.pi * np.fft.fftfreq(nx, d=dx)[None, :]
    ky = 2 * np.pi * np.fft.fftfreq(ny, d=dx)[:, None]
    ka = kx * np.cos(azimuth_rad) + ky * np.sin(azimuth_rad)
    kc = -kx * np.sin(azimuth_rad) + ky * np.cos(azimuth_rad)
    filt = np.exp(-0.25 * ((ka * corr_along_m) ** 2 + (kc * corr_across_m) ** 2))
    field_ = np.fft.ifft2(np.fft.fft2(white) * filt).real
    rms = np.sqrt(np.mean(field_**2))
    return field_ / rms if rms > 0 else field_


class _FlowLine(NamedTuple):
    """Node coordinates of a synthetic ice sheet and their place on its flow line."""

    xx: np.ndarray  # (ny, nx) x of every node [m]
    yy: np.ndarray  # (ny, nx) y of every node [m]
    xi: np.ndarray  # (ny, nx) 0 at the divide, 1 at the margin (signed)
    sgn: float  # +1 when the margin lies at larger x than the divide
    length_m: float  # L, divide to margin [m]
    divide_x_m: float


def _check_ice_sheet_args(rng, features, margin_x_m, divide_x_m, ela_fraction, bands):
    """The features asked for (a set) and L [m]; ValueError naming a bad argument."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")  # noqa: TRY004
    feats = set(features)
    unknown = feats - set(SYNTHETIC_FEATURES)
    if unknown:
        raise ValueError(f"features: unknown {sorted(unknown)}; known: {SYNTHETIC_FEATURES}")
    L = abs(float(margin_x_m) - float(divide_x_m))
    if not np.isfinite(L) or L <= 0:
        raise ValueError(f"margin_x_m must differ from divide_x_m, got {margin_x_m!r}")
    if not 0 < ela_fraction < 1:
        raise ValueError(f"ela_fraction must lie in (0, 1), got {ela_fraction!r}")
    for name, band in bands.items():
        lo, hi = (float(v) for v in band)
        if not (np.isfinite([lo, hi]).all() and 0.0 <= lo <= hi):
            raise ValueError(
                f"{name} must be (lo, hi) fractions of L with 0 <= lo <= hi, got {band!r}"
            )
    return feats, L


def _crevasses(r, z, fl: _FlowLine, y_span, dx, band_, spacing_m, depth_m):
    """``z`` with the crevasse troughs cut (see ``synthetic_ice_sheet_heightfield``)."""
    xx, yy, xi = fl.xx, fl.yy, fl.xi
    ang = r.uniform(-np.deg2rad(10), np.deg2rad(10))
    k = r.uniform(0.5, 2.0, 3) * 2 * np.pi / max(y_span, dx)
    ph = r.uniform(0, 2 * np.pi, 3)
    jitter = 0.6 * np.sum(np.sin(k[:, None, None] * yy[None] + ph[:, None, None]), axis=0)
    s = (xx - fl.divide_x_m) * fl.sgn * np.cos(ang) + yy * np.sin(ang)
    trough = np.maximum(0.0, np.cos(2 * np.pi * s / spacing_m + jitter)) ** 8
    band = (np.abs(xi) >= band_[0]) & (np.abs(xi) <= band_[1])
    return z - np.where(band, depth_m * trough, 0.0)


def _ponds(
    r,
    z,
    codes,
    fl: _FlowLine,
    y,
    ice_free,
    divide_height_m,
    n_ponds,
    pond_band,
    pond_radius_m,
    pond_depth_m,
    pond_max_basin_m,
):
    """``z`` with the melt ponds dug and flooded; their nodes become ``open_water`` in
    ``codes`` (in place)."""
    xx, yy, sgn, L, divide_x_m = fl.xx, fl.yy, fl.sgn, fl.length_m, fl.divide_x_m
    cxi = r.uniform(pond_band[0], pond_band[1], n_ponds)
    cx = divide_x_m + sgn * cxi * L
    cy = r.uniform(y[0], y[-1], n_ponds)
    rad = r.uniform(pond_radius_m[0], pond_radius_m[1], n_ponds)
    # regional surface slope at each centre: the basin must be deeper than the slope
    # drop across it to hold water (real lakes sit in bed-driven surface depressions)
    slope = np.abs(
        vialov_height(cx + rad, divide_height_m, L, divide_x_m)
        - vialov_height(cx - rad, divide_height_m, L, divide_x_m)
    ) / (2 * rad)
    for cxk, cyk, rk, gk in zip(cx, cy, rad, slope, strict=True):  # a handful of ponds
        d2 = ((xx - cxk) ** 2 + (yy - cyk) ** 2) / rk**2
        near = d2 < 4.0
        if not near.any():
            continue
        basin = pond_depth_m + min(4.0 * gk * rk, pond_max_basin_m)
        z = z - basin * np.exp(-d2) * near
        inside = d2 <= 0.64
        ring = inside & (d2 >= 0.49)
        if not ring.any():
            continue
        level = float(np.min(z[ring]))
        wet = inside & (z < level) & ~ice_free
        z[wet] = level
        codes[wet] = MATERIAL_CODES["open_water"]
    return z


def _outcrops(
    r, z, codes, fl: _FlowLine, y, n_outcrops, outcrop_band, outcrop_height_m, outcrop_radius_m
):
    """``z`` with the rock hills raised; where they rise above the ice, ``codes`` become
    ``rock`` (in place)."""
    xx, yy = fl.xx, fl.yy
    oxi = r.uniform(outcrop_band[0], outcrop_band[1], n_outcrops)
    ox = fl.divide_x_m + fl.sgn * oxi * fl.length_m
    oy = r.uniform(y[0], y[-1], n_outcrops)
    oh = r.uniform(outcrop_height_m[0], outcrop_height_m[1], n_outcrops)
    orad = r.uniform(outcrop_radius_m[0], outcrop_radius_m[1], n_outcrops)
    rock = np.zeros_like(z)
    for oxk, oyk, ohk, ork in zip(ox, oy, oh, orad, strict=True):  # a few hills
        d2 = ((xx - oxk) ** 2 + (yy - oyk) ** 2) / ork**2
        rock = np.maximum(rock, ohk * np.exp(-d2))
    above = rock > z
    codes[above] = MATERIAL_CODES["rock"]
    return np.where(above, rock, z)


def synthetic_ice_sheet_heightfield(
    extent_m,
    resolution_m,
    rng: np.random.Generator,
    *,
    divide_height_m: float,
    margin_x_m: float,
    divide_x_m: float = 0.0,
    features=SYNTHETIC_FEATURES,
    ela_fraction: float = 0.6,
    crevasse_band=(0.80, 0.95),
    crevasse_spacing_m: float = 40.0,
    crevasse_depth_m: float = 8.0,
    sastrugi_rms_m: float = 0.1,
    sastrugi_length_m=(8.0, 1.5),
    sastrugi_azimuth_rad: float = 0.0,
    pond_band=(0.6, 0.85),
    n_ponds: int = 6,
    pond_radius_m=(100.0, 400.0),
    pond_depth_m: float = 1.5,
    pond_max_basin_m: float = 10.0,
    n_outcrops: int = 4,
    outcrop_height_m=(20.0, 60.0),
    outcrop_radius_m=(60.0, 200.0),
    outcrop_band=(0.9, 1.0),
):
    """Heightfield ``(x_m, y_m, z_m, codes)`` of a simple, physically shaped ice-sheet margin.

    :func:`synthetic_ice_sheet` turns it into a :class:`Terrain` (same arguments); the scene
    loader caches the heightfield itself (the mesh is cheap to rebuild from it). ``z_m`` (ny, nx)
    is relative to the ice-free ground (0 m); ``codes`` (ny, nx) are per-node material codes.

    Surface (x is the flow-line coordinate, the sheet is extruded along y):

    * **Vialov profile** (Vialov 1958; Cuffey & Paterson 2010, eq. 8.34),
      h(x) = H [1 - (|x - x_d|/L)^(4/3)]^(3/8), H = ``divide_height_m`` at the divide x_d =
      ``divide_x_m``, zero at the margin x = ``margin_x_m`` (L = |margin_x_m - divide_x_m|);
      beyond the margin the ground is ice-free at 0 m (material ``rock``). Scale: km to 1000 km.
    * **Materials by zone**: ``snow`` up-glacier of the equilibrium line at
      ``ela_fraction`` * L from the divide, ``blue_ice`` below it (ablation zone).
    * **Crevasse field** (``"crevasses"``): parallel troughs transverse to flow in the band
      ``crevasse_band`` (fractions of L), z -= depth * max(0, cos(2 pi s / spacing + phase))^8
      with s the along-flow coordinate rotated by a seeded angle (+-10 deg) and a seeded smooth
      phase jitter across flow; spacing ``crevasse_spacing_m`` (tens of m), depth
      ``crevasse_depth_m`` (m). Needs resolution_m <~ spacing / 4 to be resolved.
    * **Sastrugi** (``"sastrugi"``): anisotropic Gaussian random relief, rms ``sastrugi_rms_m``
      (cm-dm), correlation lengths ``sastrugi_length_m`` = (along wind, across wind) (m) with the
      wind along ``sastrugi_azimuth_rad``; on snow only. Sub-resolution lengths act as per-node
      noise.
    * **Melt ponds / open water** (``"ponds"``): ``n_ponds`` seeded centres in ``pond_band``
      (fractions of L, ablation zone); each pond is a Gaussian basin of seeded radius r in
      ``pond_radius_m`` (hundreds of m) and depth ``pond_depth_m`` + min(4 * slope * r,
      ``pond_max_basin_m``) (deep enough to hold water on gentle regional slopes; on steep
      slopes only the downhill part floods), filled flat up to the lowest surface point
      of the ring at 0.7-0.8 r: a flat ``open_water`` patch at the local minimum.
    * **Rock outcrops** (``"outcrops"``): ``n_outcrops`` Gaussian hills (seeded heights in
      ``outcrop_height_m``, radii in ``outcrop_radius_m``) with centres in ``outcrop_band``
      (fractions of L; default the last 10 % of L before the margin); where the hill rises above
      the ice surface the surface is ``rock``.

    Every feature draws from its own child generator (``rng.spawn``), so disabling one does not
    change the random stream of the others; a disabled feature draws nothing.
    ``resolution_m`` is the grid step: the mesh has 2 (nx-1)(ny-1) triangles.
    """
    feats, L = _check_ice_sheet_args(
        rng,
        features,
        margin_x_m,
        divide_x_m,
        ela_fraction,
        {"crevasse_band": crevasse_band, "pond_band": pond_band, "outcrop_band": outcrop_band},
    )
    x, y = _grid(extent_m, resolution_m)
    dx = float(x[1] - x[0])
    xx, yy = np.meshgrid(x, y)
    sgn = 1.0 if margin_x_m > divide_x_m else -1.0
    fl = _FlowLine(xx, yy, sgn * (xx - divide_x_m) / L, sgn, L, divide_x_m)
    ice = vialov_height(xx, divide_height_m, L, divide_x_m)
    ice[fl.xi < -1.0] = 0.0
    ice_free = np.abs(fl.xi) >= 1.0
    z = ice.copy()
    codes = np.where(
        np.abs(fl.xi) < ela_fraction, MATERIAL_CODES["snow"], MATERIAL_CODES["blue_ice"]
    ).astype(np.int32)
    codes[ice_free] = MATERIAL_CODES["rock"]
    # one child generator per feature, whether or not it is drawn from
    g = dict(zip(SYNTHETIC_FEATURES, rng.spawn(len(SYNTHETIC_FEATURES)), strict=True))
    if "crevasses" in feats and crevasse_depth_m > 0:
        z = _crevasses(
            g["crevasses"],
            z,
            fl,
            float(y[-1] - y[0]),
            dx,
            crevasse_band,
            crevasse_spacing_m,
            crevasse_depth_m,
        )
    if "sastrugi" in feats and sastrugi_rms_m > 0:
        noise = _smooth_noise(
            g["sastrugi"],
            z.shape,
            dx,
            sastrugi_length_m[0],
            sastrugi_length_m[1],
            sastrugi_azimuth_rad,
        )
        z = z + np.where(codes == MATERIAL_CODES["snow"], sastrugi_rms_m * noise, 0.0)
    if "ponds" in feats and n_ponds > 0:
        z = _ponds(
            g["ponds"],
            z,
            codes,
            fl,
            y,
            ice_free,
            divide_height_m,
            n_ponds,
            pond_band,
            pond_radius_m,
            pond_depth_m,
            pond_max_basin_m,
        )
    if "outcrops" in feats and n_outcrops > 0:
        z = _outcrops(
            g["outcrops"],
            z,
            codes,
            fl,
            y,
            n_outcrops,
            outcrop_band,
            outcrop_height_m,
            outcrop_radius_m,
        )
    return x, y, z, codes


def synthetic_ice_sheet(extent_m, resolution_m, rng: np.random.Generator, **params) -> Terrain:
    return Terrain.from_heightfield(
        *synthetic_ice_sheet_heightfield(extent_m, resolution_m, rng, **params)
    )


synthetic_ice_sheet.__doc__ = (
    "A :class:`Terrain` from :func:`synthetic_ice_sheet_heightfield` (same arguments).\n\n"
    + (synthetic_ice_sheet_heightfield.__doc__ or "")
)


#: The functions whose source defines the generated heightfields: the scene loader hashes their
#: source into its cache key, so editing any of them invalidates cached terrain.
HEIGHTFIELD_GENERATORS = (
    synthetic_ice_sheet_heightfield,
    _check_ice_sheet_args,
    _crevasses,
    _ponds,
    _outcrops,
    vialov_height,
    _smooth_noise,
    _grid,
    _extent,
    flat_plane_heightfield,
    sloped_plane_heightfield,
)
