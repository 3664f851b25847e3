"""Atmosphere: Cn^2 profiles, r0 / coherence radius / Rytov variance, Gaussian-beam spread and
wander, transmission, phase screens (static and moving with the platform), and fiber coupling
through turbulence. SI units throughout; see docs/explanation/validation/atmosphere.md.

Public API:

* turbulence: ``cn2_hufnagel_valley``, ``hufnagel_valley_profile``, ``constant_profile``,
  ``fried_parameter``, ``fried_parameter_profile``, ``coherence_radius``, ``rytov_variance``,
  ``rytov_variance_profile``, ``isoplanatic_angle``, ``cn2_path_integral``, ``slant_path_length``
* beam: ``gaussian_beam_parameters``, ``long_term_beam_radius``, ``beam_wander_variance``
* transmission: ``beer_lambert_transmission``, ``one_way_power_transmission``,
  ``round_trip_power_transmission``
* screens: ``phase_screen``, ``phase_screens``, ``von_karman_psd``,
  ``von_karman_structure_function``, ``kolmogorov_structure_function``, ``von_karman_covariance``,
  ``von_karman_phase_variance``, ``structure_function_from_psd``,
  ``expected_screen_structure_function``, ``screen_structure_function_lattice``,
  ``structure_function_estimate``, ``ResolutionWarning``
* moving screen: ``MovingScreen``
* coupling: ``turbulent_coupling``, ``turbulent_coupling_samples``, ``turbulent_coupling_mean``,
  ``turbulent_coupling_exact``, ``turbulent_coupling_screen_expectation``,
  ``grouped_standard_error``
"""

from ..lazy import lazy_exports

# Imported on first use (PEP 562): the submodules pull in scipy.
__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "beam": ("beam_wander_variance", "gaussian_beam_parameters", "long_term_beam_radius"),
        "coupling": (
            "COUPLING_SUBHARMONIC_LEVELS",
            "grouped_standard_error",
            "turbulent_coupling",
            "turbulent_coupling_exact",
            "turbulent_coupling_mean",
            "turbulent_coupling_samples",
            "turbulent_coupling_screen_expectation",
        ),
        "moving": ("MovingScreen",),
        "screens": (
            "KOLMOGOROV_SF_COEFF",
            "PSD_COEFF",
            "ResolutionWarning",
            "expected_screen_structure_function",
            "kolmogorov_structure_function",
            "phase_screen",
            "phase_screens",
            "screen_structure_function_lattice",
            "structure_function_estimate",
            "structure_function_from_psd",
            "von_karman_covariance",
            "von_karman_phase_variance",
            "von_karman_psd",
            "von_karman_structure_function",
        ),
        "transmission": (
            "beer_lambert_transmission",
            "one_way_power_transmission",
            "round_trip_power_transmission",
        ),
        "turbulence": (
            "HV57_GROUND_CN2",
            "HV57_RMS_WIND_MPS",
            "cn2_hufnagel_valley",
            "cn2_path_integral",
            "coherence_radius",
            "constant_profile",
            "fried_parameter",
            "fried_parameter_profile",
            "hufnagel_valley_profile",
            "isoplanatic_angle",
            "rytov_variance",
            "rytov_variance_profile",
            "slant_path_length",
        ),
    },
)

__all__ = [
    "COUPLING_SUBHARMONIC_LEVELS",
    "HV57_GROUND_CN2",
    "HV57_RMS_WIND_MPS",
    "KOLMOGOROV_SF_COEFF",
    "PSD_COEFF",
    "MovingScreen",
    "ResolutionWarning",
    "beam_wander_variance",
    "beer_lambert_transmission",
    "cn2_hufnagel_valley",
    "cn2_path_integral",
    "coherence_radius",
    "constant_profile",
    "expected_screen_structure_function",
    "fried_parameter",
    "fried_parameter_profile",
    "gaussian_beam_parameters",
    "grouped_standard_error",
    "hufnagel_valley_profile",
    "isoplanatic_angle",
    "kolmogorov_structure_function",
    "long_term_beam_radius",
    "one_way_power_transmission",
    "phase_screen",
    "phase_screens",
    "round_trip_power_transmission",
    "rytov_variance",
    "rytov_variance_profile",
    "screen_structure_function_lattice",
    "slant_path_length",
    "structure_function_estimate",
    "structure_function_from_psd",
    "turbulent_coupling",
    "turbulent_coupling_exact",
    "turbulent_coupling_mean",
    "turbulent_coupling_samples",
    "turbulent_coupling_screen_expectation",
    "von_karman_covariance",
    "von_karman_phase_variance",
    "von_karman_psd",
    "von_karman_structure_function",
]
