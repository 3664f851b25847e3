"""Targets: Lambertian and specular reflectance, surface materials, speckle.

Kernels on numpy arrays in SI units; see docs/explanation/validation/targets.md for the formulas
and sources.
"""

from ..lazy import lazy_exports

# Imported on first use (PEP 562): the submodules pull in scipy.
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "materials": (
            "MATERIALS",
            "Material",
            "get_material",
            "ice_refractive_index",
            "snow_albedo_art",
            "water_refractive_index",
        ),
        "reflectance": (
            "cox_munk_mss",
            "facing_away",
            "fresnel_reflectance",
            "lambertian_power_fraction",
            "receiver_cone_half_angle_rad",
            "specular_return_fraction",
        ),
        "speckle": (
            "correlated_speckle",
            "correlated_speckle_field",
            "speckle_cells",
            "speckle_contrast_finite",
            "speckle_decorrelation",
            "speckle_phase",
            "speckle_power",
            "surface_scatterer_count",
        ),
    },
)

__all__ = [
    "MATERIALS",
    "Material",
    "correlated_speckle",
    "correlated_speckle_field",
    "cox_munk_mss",
    "facing_away",
    "fresnel_reflectance",
    "get_material",
    "ice_refractive_index",
    "lambertian_power_fraction",
    "receiver_cone_half_angle_rad",
    "snow_albedo_art",
    "speckle_cells",
    "speckle_contrast_finite",
    "speckle_decorrelation",
    "speckle_phase",
    "speckle_power",
    "specular_return_fraction",
    "surface_scatterer_count",
    "water_refractive_index",
]
