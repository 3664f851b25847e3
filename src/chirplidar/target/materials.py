"""Surface materials at the instrument wavelength, each with its source.

``Material.reflectivity`` is what the channel multiplies into the link budget:

* ``scattering == "lambertian"``: the reflectance rho of ``lambertian_power_fraction`` (a
  directional-hemispherical reflectance, taken at normal incidence);
* ``scattering == "specular"``: the facet power reflectance at normal incidence, rho_F of
  ``specular_return_fraction`` (the return then depends on the slope distribution and geometry).

Values are tabulated at 1064, 1310 and 1550 nm where a source or a stated model gives one. Every
``source`` says whether the number is a measurement, a computation from published constants with
a published model (and which parameters were assumed), or an order-of-magnitude estimate.

Ice absorbs strongly in the near infrared (Warren & Brandt 2008: k = 1.9e-6 at 1064 nm, 1.3e-5 at
1310 nm, 4.2e-4 at 1550 nm; absorption lengths 4.5 cm, 8 mm, 0.3 mm), so snow is far darker at
1310 nm than in the visible and very dark at 1550 nm, and coarse grains (firn) darker than fine.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

import numpy as np

from .._checks import out, positive_array, real_array
from .reflectance import fresnel_reflectance

# Warren & Brandt (2008), "Optical constants of ice from the ultraviolet to the microwave: a revised
# compilation", J. Geophys. Res. 113, D14220 (table IOP_2008_ASCIItable.dat at
# https://atmos.uw.edu/ice_optical_constants/), rows 0.95-1.65 um: wavelength (um), n, k. Copied
# from the redistribution of that table in biosnicar-py (Data/ice_optical_constants.csv).
_WB08_NIR = np.array(
    [
        (0.95, 1.3023, 6.02e-7),
        (0.96, 1.3022, 7.55e-7),
        (0.97, 1.3020, 9.26e-7),
        (0.98, 1.3019, 1.12e-6),
        (0.99, 1.3017, 1.33e-6),
        (1.00, 1.3015, 1.62e-6),
        (1.01, 1.3014, 2.00e-6),
        (1.02, 1.3012, 2.25e-6),
        (1.03, 1.3010, 2.33e-6),
        (1.04, 1.3009, 2.33e-6),
        (1.05, 1.3007, 2.17e-6),
        (1.06, 1.3005, 1.96e-6),
        (1.07, 1.3003, 1.81e-6),
        (1.08, 1.3002, 1.74e-6),
        (1.09, 1.3000, 1.73e-6),
        (1.10, 1.2998, 1.70e-6),
        (1.11, 1.2997, 1.76e-6),
        (1.12, 1.2995, 1.82e-6),
        (1.13, 1.2993, 2.04e-6),
        (1.14, 1.2991, 2.25e-6),
        (1.15, 1.2990, 2.29e-6),
        (1.16, 1.2988, 3.04e-6),
        (1.17, 1.2986, 3.84e-6),
        (1.18, 1.2984, 4.77e-6),
        (1.19, 1.2982, 5.76e-6),
        (1.20, 1.2980, 6.71e-6),
        (1.21, 1.2979, 8.66e-6),
        (1.22, 1.2977, 1.02e-5),
        (1.23, 1.2975, 1.13e-5),
        (1.24, 1.2973, 1.22e-5),
        (1.25, 1.2971, 1.29e-5),
        (1.26, 1.2969, 1.32e-5),
        (1.27, 1.2967, 1.35e-5),
        (1.28, 1.2965, 1.33e-5),
        (1.29, 1.2963, 1.32e-5),
        (1.30, 1.2961, 1.32e-5),
        (1.31, 1.2959, 1.31e-5),
        (1.32, 1.2957, 1.32e-5),
        (1.33, 1.2955, 1.32e-5),
        (1.34, 1.2953, 1.34e-5),
        (1.35, 1.2951, 1.39e-5),
        (1.36, 1.2949, 1.42e-5),
        (1.37, 1.2946, 1.48e-5),
        (1.38, 1.2944, 1.58e-5),
        (1.39, 1.2941, 1.74e-5),
        (1.40, 1.2939, 1.98e-5),
        (1.41, 1.2937, 3.442e-5),
        (1.42, 1.2934, 5.959e-5),
        (1.43, 1.2931, 1.028e-4),
        (1.44, 1.2929, 1.516e-4),
        (1.449, 1.2927, 2.030e-4),
        (1.46, 1.2924, 2.942e-4),
        (1.471, 1.2921, 3.987e-4),
        (1.481, 1.2920, 4.941e-4),
        (1.493, 1.2918, 5.532e-4),
        (1.504, 1.2916, 5.373e-4),
        (1.515, 1.2914, 5.143e-4),
        (1.527, 1.2912, 4.908e-4),
        (1.538, 1.2909, 4.594e-4),
        (1.563, 1.2903, 3.858e-4),
        (1.587, 1.2897, 3.105e-4),
        (1.613, 1.2890, 2.659e-4),
        (1.65, 1.2879, 2.361e-4),
    ]
)
_WB08_LOG_WL = np.log(_WB08_NIR[:, 0] * 1e-6)

ICE_DENSITY_KG_M3 = 917.0

# Snow grain shape parameters of the asymptotic radiative transfer (ART) albedo: absorption
# enhancement B and asymmetry g, as used by Libois et al. (2013, The Cryosphere 7, 1803) and
# Picard's snowoptics (B = 1.6, g = 0.845).
ART_B = 1.6
ART_G = 0.845
# Largest single-scattering co-albedo accepted: ART is a weak-absorption expansion.
ART_MAX_COALBEDO = 0.1


def ice_refractive_index(wavelength_m):
    """Complex refractive index n + i k of ice Ih, Warren & Brandt (2008), 0.95-1.65 um.

    wavelength_m: vacuum wavelength (m), array. n is interpolated linearly and k log-linearly in
    log wavelength (the interpolation the WB08 web page recommends). Outside 0.95-1.65 um:
    ValueError (only that part of the table is carried). Returns complex128.
    """
    wl = positive_array("wavelength_m", wavelength_m)
    lo, hi = _WB08_NIR[0, 0] * 1e-6, _WB08_NIR[-1, 0] * 1e-6
    if np.any((wl < lo) | (wl > hi)):
        raise ValueError(
            f"wavelength_m must lie in [{lo:.3g}, {hi:.3g}] m (the part of the "
            "Warren & Brandt 2008 table carried here)"
        )
    x = np.log(wl)
    n = np.interp(x, _WB08_LOG_WL, _WB08_NIR[:, 1])
    k = np.exp(np.interp(x, _WB08_LOG_WL, np.log(_WB08_NIR[:, 2])))
    r = n + 1j * k
    return complex(r) if r.ndim == 0 else r


# IAPWS R9-97, "Release on the Refractive Index of Ordinary Water Substance as a Function of
# Wavelength, Temperature and Pressure" (1997); Harvey et al., J. Phys. Chem. Ref. Data 27, 761
# (1998). (n^2 - 1)/(n^2 + 2) / rho_bar = a0 + a1 rho + a2 T + a3 lam^2 T + a4/lam^2
#     + a5/(lam^2 - lam_uv^2) + a6/(lam^2 - lam_ir^2) + a7 rho^2, reduced by 1000 kg/m^3, 273.15 K,
# 0.589 um.
_IAPWS_A = (
    0.244257733,
    9.74634476e-3,
    -3.73234996e-3,
    2.68678472e-4,
    1.58920570e-3,
    2.45934259e-3,
    0.900704920,
    -1.66626219e-2,
)
_IAPWS_LAM_UV = 0.2292020
_IAPWS_LAM_IR = 5.432937


def water_refractive_index(wavelength_m, temperature_k, density_kg_m3):
    """Real refractive index of liquid water (relative to vacuum), IAPWS R9-97.

    wavelength_m: vacuum wavelength (m), 0.2-1.9 um; temperature_k: 261.15-773.15 K;
    density_kg_m3: 0-1060 kg/m^3 (999.84 at 0 degC, 998.21 at 20 degC, 1 atm). Returns float64.
    The release's stated validity is 0.2-1.1 um; 1.31 and 1.55 um are an extrapolation (about
    +-0.003 in n, +-2 % in the normal-incidence Fresnel reflectance). Sea water of salinity 35 has
    n larger by about 0.006 (Quan & Fry 1995, Appl. Opt. 34, 3477, visible).
    """
    wl = positive_array("wavelength_m", wavelength_m)
    t = positive_array("temperature_k", temperature_k)
    rho = positive_array("density_kg_m3", density_kg_m3)
    if np.any((wl < 0.2e-6) | (wl > 1.9e-6)):
        raise ValueError("wavelength_m must lie in [0.2e-6, 1.9e-6] m (IAPWS R9-97)")
    if np.any((t < 261.15) | (t > 773.15)):
        raise ValueError("temperature_k must lie in [261.15, 773.15] K (IAPWS R9-97)")
    if np.any(rho > 1060.0):
        raise ValueError("density_kg_m3 must be <= 1060 kg/m^3 (IAPWS R9-97)")
    a = _IAPWS_A
    lam = wl / 0.589e-6
    tb = t / 273.15
    rb = rho / 1000.0
    lam2 = lam**2
    lhs = (
        a[0]
        + a[1] * rb
        + a[2] * tb
        + a[3] * lam2 * tb
        + a[4] / lam2
        + a[5] / (lam2 - _IAPWS_LAM_UV**2)
        + a[6] / (lam2 - _IAPWS_LAM_IR**2)
        + a[7] * rb**2
    )
    big_a = lhs * rb
    return out(np.sqrt((1.0 + 2.0 * big_a) / (1.0 - big_a)))


def snow_albedo_art(wavelength_m, ssa_m2_per_kg, incidence_rad):
    """Plane (directional-hemispherical) albedo of deep, clean snow by asymptotic radiative transfer.

    wavelength_m: 0.95-1.65 um (ice constants from ``ice_refractive_index``);
    ssa_m2_per_kg: specific surface area (m^2/kg; optical diameter d = 6/(917 SSA): 60 fresh snow,
    20-40 settled, < 10 coarse/old); incidence_rad: direct-beam incidence angle (rad, < pi/2).

    Kokhanovsky & Zege (2004, Appl. Opt. 43, 1589): co-albedo w = 2 B gamma / (SSA rho_ice) with
    gamma = 4 pi k / lambda, alpha = 16 w / (3 (1 - g)), albedo = exp(-sqrt(alpha) 3 (1 + 2 mu0)/7),
    mu0 = cos(incidence), B = 1.6, g = 0.845 (the form of Picard's snowoptics ``albedo_direct_KZ04``).
    ART is a weak-absorption theory: co-albedos above 0.1 (e.g. 1550 nm at any realistic grain
    size) raise ValueError instead of returning a number outside its validity. Near that limit
    (albedo below about 0.2) treat the result as +-30 %.
    """
    wl = positive_array("wavelength_m", wavelength_m)
    ssa = positive_array("ssa_m2_per_kg", ssa_m2_per_kg)
    theta = real_array("incidence_rad", incidence_rad)
    if np.any((theta < 0.0) | (theta >= 0.5 * np.pi)):
        raise ValueError("incidence_rad must lie in [0, pi/2)")
    k = np.imag(ice_refractive_index(wl))
    gamma = 4.0 * np.pi * k / wl
    coalbedo = 2.0 * ART_B * gamma / (ssa * ICE_DENSITY_KG_M3)
    if np.any(coalbedo > ART_MAX_COALBEDO):
        raise ValueError(
            f"single-scattering co-albedo {np.max(coalbedo):.3g} > "
            f"{ART_MAX_COALBEDO}: ice absorbs too strongly at this wavelength_m and "
            "ssa_m2_per_kg for the asymptotic (weak-absorption) theory"
        )
    alpha = 16.0 / 3.0 * coalbedo / (1.0 - ART_G)
    mu0 = np.cos(theta)
    return out(np.exp(-np.sqrt(alpha) * 3.0 * (1.0 + 2.0 * mu0) / 7.0))


def _bubbly_ice_albedo(
    wavelength_m: float, bubble_radius_m: float, bubble_fraction: float
) -> float:
    """Asymptotic albedo of bubbly ice, exp(-4 sqrt(gamma (4a/3) / (3 f (1 - g)))), g = 0.79.

    The form of Picard's snowoptics ``albedo_diffuse_bubbly_ice`` (ART applied to bubbles in ice).
    """
    k = np.imag(ice_refractive_index(wavelength_m))
    gamma = (1.0 - bubble_fraction) * 4.0 * np.pi * k / wavelength_m
    y = 4.0 * np.sqrt(
        gamma * (4.0 / 3.0 * bubble_radius_m) / (3.0 * bubble_fraction * (1.0 - 0.79))
    )
    return float(np.exp(-y))


@dataclass(frozen=True)
class Material:
    """A surface material: reflectivity tabulated against wavelength, scattering kind and source.

    wavelengths_m: increasing tuple of vacuum wavelengths (m); reflectivity: values in [0, 1]
    (meaning depends on ``scattering``, see the module docstring); source: where every number
    comes from and how approximate it is.
    """

    name: str
    scattering: Literal["lambertian", "specular"]
    wavelengths_m: tuple[float, ...]
    reflectivity: tuple[float, ...]
    source: str

    def __post_init__(self):
        if self.scattering not in ("lambertian", "specular"):
            raise ValueError(
                f"scattering must be 'lambertian' or 'specular', got {self.scattering!r}"
            )
        wl = np.asarray(self.wavelengths_m, dtype=float)
        r = np.asarray(self.reflectivity, dtype=float)
        if wl.ndim != 1 or wl.size == 0 or wl.shape != r.shape:
            raise ValueError("wavelengths_m and reflectivity must be equally long, non-empty")
        if np.any(~np.isfinite(wl)) or np.any(wl <= 0) or np.any(np.diff(wl) <= 0):
            raise ValueError("wavelengths_m must be positive and strictly increasing")
        if np.any(~np.isfinite(r)) or np.any((r < 0) | (r > 1)):
            raise ValueError("reflectivity must lie in [0, 1]")
        if not self.source.strip():
            raise ValueError("source must say where the values come from")

    #: Tolerance outside the tabulated range (m): a laser within 1 nm of a tabulated line gets it.
    TOLERANCE_M = 1e-9

    def reflectivity_at(self, wavelength_m):
        """Reflectivity at ``wavelength_m`` (m): linear interpolation between tabulated values.

        Within 1 nm of the tabulated range the end value is used; further out: ValueError (no
        extrapolation). Interpolation is not a spectrum: between 1310 and 1550 nm it misses the
        1.45-1.5 um ice absorption band, where snow is darker than at either end.
        """
        wl = positive_array("wavelength_m", wavelength_m)
        lo, hi = self.wavelengths_m[0], self.wavelengths_m[-1]
        if np.any((wl < lo - self.TOLERANCE_M) | (wl > hi + self.TOLERANCE_M)):
            raise ValueError(
                f"wavelength_m outside the range tabulated for {self.name!r}: "
                f"{lo * 1e9:.0f}-{hi * 1e9:.0f} nm"
            )
        return out(np.interp(wl, self.wavelengths_m, self.reflectivity))


_LINES_M = (1064e-9, 1310e-9, 1550e-9)


def _snow(name: str, ssa: float, r1550: float, what: str) -> Material:
    r = tuple(float(snow_albedo_art(wl, ssa, 0.0)) for wl in _LINES_M[:2]) + (r1550,)
    return Material(
        name,
        "lambertian",
        _LINES_M,
        r,
        f"{what}. 1064/1310 nm: computed, plane albedo at normal incidence by asymptotic radiative "
        f"transfer (Kokhanovsky & Zege 2004; B = {ART_B}, g = {ART_G}) with Warren & Brandt (2008) "
        f"ice absorption, for an assumed SSA of {ssa:g} m^2/kg (optical diameter "
        f"{6e3 / (ICE_DENSITY_KG_M3 * ssa):.2f} mm); grain size is the dominant uncertainty "
        "(see snow_albedo_art for other sizes); albedo used as the Lambertian rho. 1550 nm: "
        f"order-of-magnitude estimate {r1550:g} (factor ~3): ice is opaque over ~0.3 mm there, ART "
        "does not apply, and the return is mostly single external reflection from grain faces "
        "(a few %); consistent with the very low 1.5-1.6 um snow albedo of Wiscombe & Warren "
        "(1980, J. Atmos. Sci. 37, 2712) (qualitative, not a figure reading).",
    )


def _blue_ice() -> Material:
    bubble_radius_m, bubble_fraction = 0.2e-3, 0.01
    vals = []
    for wl in _LINES_M:
        n_ice = float(np.real(ice_refractive_index(wl)))
        vals.append(
            float(fresnel_reflectance(n_ice, 0.0))
            + _bubbly_ice_albedo(wl, bubble_radius_m, bubble_fraction)
        )
    return Material(
        "blue_ice",
        "lambertian",
        _LINES_M,
        tuple(vals),
        "Model estimate, not a measurement: surface Fresnel reflectance of ice at normal incidence "
        "from Warren & Brandt (2008) n (0.017), counted as diffuse (a scalloped, rough surface), "
        "plus bubble volume scattering by the asymptotic bubbly-ice albedo (snowoptics "
        "albedo_diffuse_bubbly_ice form) for assumed bubbles of 0.2 mm radius at 1 % volume: "
        "~0.02 at 1064 nm, negligible at 1310/1550 nm where the absorption length (8 mm, 0.3 mm) "
        "is shorter than the bubble spacing. Smooth blue ice near nadir can return much more: "
        "use the specular model with a facet-slope distribution for it.",
    )


def _open_water() -> Material:
    vals = tuple(
        float(fresnel_reflectance(water_refractive_index(wl, 273.15, 999.84), 0.0))
        for wl in _LINES_M
    )
    return Material(
        "open_water",
        "specular",
        _LINES_M,
        vals,
        "Computed: Fresnel reflectance at normal incidence, ((n-1)/(n+1))^2, with n of fresh water "
        "at 0 degC from IAPWS R9-97 (1.325, 1.321, 1.316; extrapolated beyond 1.1 um, +-0.003). "
        "Sea water (S = 35) raises n by ~0.006 and R by ~0.0007. Specular: the return is set by "
        "the slope distribution (Cox & Munk 1954, cox_munk_mss) and geometry "
        "(specular_return_fraction). Water absorbs within millimetres at these wavelengths "
        "(Hale & Querry 1973), so there is no volume return.",
    )


_ROCK = Material(
    "rock",
    "lambertian",
    _LINES_M,
    (0.2, 0.2, 0.2),
    "Representative value, not read from a specific spectrum: rock and soil spectra in the USGS "
    "Spectral Library v7 (Kokaly et al. 2017, USGS Data Series 1035) are smooth between 1.0 and "
    "1.6 um and span roughly 0.05 (basalt, dark volcanic rock) to 0.3-0.4 (granite, sandstone, "
    "weathered surfaces). Take the library spectrum of the actual rock type where it matters.",
)

_THESIS_TARGET = Material(
    "thesis_target",
    "lambertian",
    (1310e-9,),
    (0.46,),
    "Thesis Table 4.6, atm.R_trg = 0.460 W/W (target power reflectivity of the simulation "
    "parameters; 1310 nm instrument).",
)

MATERIALS = MappingProxyType(
    {
        m.name: m
        for m in (
            _snow("snow_fresh", 60.0, 0.04, "Fresh dry snow"),
            _snow("snow", 25.0, 0.03, "Settled dry surface snow (ice-sheet accumulation zone)"),
            _snow(
                "firn",
                8.0,
                0.02,
                "Coarse old snow / firn at the surface (rounded, melt-affected grains)",
            ),
            _blue_ice(),
            _open_water(),
            _ROCK,
            _THESIS_TARGET,
        )
    }
)


def get_material(name: str) -> Material:
    """The material called ``name``; ValueError listing the known names otherwise."""
    try:
        return MATERIALS[name]
    except KeyError:
        raise ValueError(
            f"unknown material {name!r}; known: {', '.join(sorted(MATERIALS))}"
        ) from None
