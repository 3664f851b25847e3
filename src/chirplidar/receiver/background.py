"""Background light in a direct-detection receiver: the standard lidar background equation
(Measures 1984, "Laser Remote Sensing", Sec. 7.2; Gardner 1992, IEEE TGRS 30(5) 1061, eq. 21).

A Lambertian surface of reflectance rho lit by the sun at elevation el under a spectral
irradiance E (top of the atmosphere, W m^-2 m^-1) through a one-way transmission T has the
spectral radiance

    L = rho E sin(el) T / pi          [W m^-2 sr^-1 m^-1]    (0 when the sun is below the horizon)

and a receiver of aperture A_r = pi D^2 / 4, full field of view fov (solid angle
Omega = pi (fov / 2)^2, small angle), filter width d_lambda and optical transmission T_opt
collects

    P_b = L d_lambda A_r Omega T_opt  [W].
"""

from __future__ import annotations

import numpy as np

from .._checks import non_negative_array, positive, unit_interval_array


def surface_solar_radiance_w_m2_sr_m(
    solar_irradiance_w_m2_m, sun_elevation_rad, reflectance, one_way_transmission
):
    """rho E sin(el) T / pi [W m^-2 sr^-1 m^-1]: the radiance of a Lambertian surface in
    sunlight (0 for el <= 0, the sun below the horizon). Arrays broadcast."""
    e = non_negative_array("solar_irradiance_w_m2_m", solar_irradiance_w_m2_m)
    el = np.asarray(sun_elevation_rad, float)
    if not np.all(np.isfinite(el)):
        raise ValueError("sun_elevation_rad must be finite")
    rho = unit_interval_array("reflectance", reflectance)
    t = unit_interval_array("one_way_transmission", one_way_transmission)
    return (rho * e * np.clip(np.sin(el), 0.0, None) * t / np.pi)[()]


def background_power_w(
    radiance_w_m2_sr_m,
    filter_bandwidth_m: float,
    telescope_diameter_m: float,
    field_of_view_rad: float,
    optical_transmission: float,
):
    """L d_lambda A_r Omega T_opt [W], A_r = pi D^2 / 4 and Omega = pi (fov / 2)^2: the
    background power a receiver collects from a radiance ``radiance_w_m2_sr_m`` filling its
    field of view (full angle ``field_of_view_rad``)."""
    radiance = non_negative_array("radiance_w_m2_sr_m", radiance_w_m2_sr_m)
    positive("filter_bandwidth_m", filter_bandwidth_m)
    positive("telescope_diameter_m", telescope_diameter_m)
    positive("field_of_view_rad", field_of_view_rad)
    t_opt = float(unit_interval_array("optical_transmission", optical_transmission))
    area = np.pi * telescope_diameter_m**2 / 4.0
    omega = np.pi * (field_of_view_rad / 2.0) ** 2
    return (radiance * filter_bandwidth_m * area * omega * t_opt)[()]
