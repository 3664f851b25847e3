"""Thesis parameter names (Tables 4.1-4.9, 4.11) and the project keys they stand for.

One table serves ``--set``, TOML loading and the README mapping table. Each row:
(thesis name, project key, thesis unit, thesis table).
"""

from __future__ import annotations

THESIS_TABLE: tuple[tuple[str, str, str, str], ...] = (
    # Table 4.1 - Globals
    ("sims.T", "simulation.duration_s", "s", "4.1"),
    ("sims.Fs", "simulation.sample_rate_hz", "Hz", "4.1"),
    ("sims.upxn", "simulation.upsample_factor", "integer", "4.1"),
    # Table 4.2 - System selection
    ("sys.rsel", "system.receiver", "APD | COH | PIN", "4.2"),
    ("sys.CxMode", "system.coherent_mode", "hom | het", "4.2"),
    ("sys.MxMode", "system.modulation", "FM | PN", "4.2"),
    ("sys.smoothx", "processing.zero_pad_factor", "integer", "4.2"),
    ("sys.avg", "processing.averages", "integer", "4.2"),
    ("sys.fmaxopt", "system.max_beat_frequency_hz", "Hz", "4.2"),
    ("sys.f_highpass", "processing.highpass_hz", "Hz", "4.2"),
    ("sys.BWres", "processing.rbw_hz", "Hz", "4.2"),
    # Table 4.3 - Chirp waveform
    ("chrp.Tchp", "waveform.chirp_period_s", "s", "4.3"),
    ("chrp.F1", "waveform.f_start_hz", "Hz", "4.3"),
    ("chrp.F2", "waveform.f_stop_hz", "Hz", "4.3"),
    ("chrp.F0", "waveform.f_offset_hz", "Hz", "4.3"),
    ("chrp.rdcyc", "waveform.ramp_duty_cycle", "fraction", "4.3"),
    ("chrp.adcyc", "waveform.amplitude_duty_cycle", "fraction", "4.3"),
    ("chrp.qnt", "waveform.hold_time_s", "s", "4.3"),
    ("chrp.Vpp", "waveform.vpp_v", "V", "4.3"),
    ("chrp.Vdc", "waveform.vdc_v", "V", "4.3"),
    ("chrp.Ro", "waveform.output_impedance_ohm", "Ohm", "4.3"),
    # Table 4.4 - Laser source
    ("lsr.Lo", "laser.wavelength_m", "m", "4.4"),
    ("lsr.Po", "laser.power_w", "W", "4.4"),
    ("lsr.Lw", "laser.linewidth_hz", "Hz", "4.4"),
    # Table 4.5 - Mach-Zehnder modulator
    ("mzm.Vpi", "modulator.v_pi_v", "V", "4.5"),
    ("mzm.Vdc", "modulator.bias_v", "V", "4.5"),
    ("mzm.Ri", "modulator.input_impedance_ohm", "Ohm", "4.5"),
    # Table 4.6 - Transmission channel
    ("atm.Pattn", "channel.extra_attenuation_db", "dB", "4.6"),
    ("atm.state", "channel.free_space", "on | off", "4.6"),
    ("atm.dst", "channel.distance_m", "m", "4.6"),
    ("atm.Cn2", "channel.cn2_m_minus_2_3", "m^-2/3", "4.6"),
    ("atm.lc", "channel.surface_correlation_length_m", "m", "4.6"),
    ("atm.Wo", "channel.beam_radius_m", "m", "4.6"),
    ("atm.div", "channel.divergence_half_angle_rad", "rad", "4.6"),
    ("atm.Wr", "channel.target_radius_m", "m", "4.6"),
    ("atm.R_trg", "channel.target_reflectivity", "W/W", "4.6"),
    ("atm.D_tel", "channel.telescope_diameter_m", "m", "4.6"),
    ("atm.T_atm", "channel.atmospheric_transmission", "V/V", "4.6"),
    ("atm.T_opt", "channel.optical_transmission", "V/V", "4.6"),
    # Table 4.7 - APD photodetector
    ("APD.Tfb", "apd.feedback_temperature_k", "K", "4.7"),
    ("APD.Tdet", "apd.detector_temperature_k", "K", "4.7"),
    ("APD.Rfb", "apd.feedback_resistance_ohm", "Ohm", "4.7"),
    ("APD.Cfb", "apd.feedback_capacitance_f", "F", "4.7"),
    ("APD.INin", "apd.amp_current_noise_a_per_rthz", "A/rtHz", "4.7"),
    ("APD.VNen", "apd.amp_voltage_noise_v_per_rthz", "V/rtHz", "4.7"),
    ("APD.Ro", "apd.dynamic_resistance_ohm", "Ohm", "4.7"),
    ("APD.Cdet", "apd.detector_capacitance_f", "F", "4.7"),
    ("APD.M", "apd.gain", "-", "4.7"),
    ("APD.NF", "apd.excess_noise_factor", "-", "4.7"),
    ("APD.Isol", "apd.solar_current_a", "A", "4.7"),
    ("APD.Ibgd", "apd.background_current_a", "A", "4.7"),
    ("APD.Ilkg", "apd.leakage_current_a", "A", "4.7"),
    ("APD.qe", "apd.quantum_efficiency", "-", "4.7"),
    ("APD.fo", "apd.center_frequency_hz", "Hz", "4.7"),
    # Table 4.8 - Balanced photodetector
    ("COH.To", "balanced.noise_temperature_k", "K", "4.8"),
    ("COH.Ro", "balanced.output_impedance_ohm", "Ohm", "4.8"),
    ("COH.P_LO", "balanced.lo_power_w", "W", "4.8"),
    ("COH.f_LO", "balanced.lo_offset_hz", "Hz", "4.8"),
    ("COH.lw", "balanced.lo_linewidth_hz", "Hz", "4.8"),
    ("COH.Isol", "balanced.solar_current_a", "A", "4.8"),
    ("COH.Ibgd", "balanced.background_current_a", "A", "4.8"),
    ("COH.Ilkg", "balanced.leakage_current_a", "A", "4.8"),
    ("COH.Nep", "balanced.nep_w_per_rthz", "W/rtHz", "4.8"),
    ("COH.qe1", "balanced.quantum_efficiency_1", "-", "4.8"),
    ("COH.qe2", "balanced.quantum_efficiency_2", "-", "4.8"),
    ("COH.Ztia", "balanced.transimpedance_ohm", "V/A", "4.8"),
    # Table 4.9 - PIN photodetector
    ("PIN.B", "pin.bandwidth_hz", "Hz", "4.9"),
    ("PIN.To", "pin.noise_temperature_k", "K", "4.9"),
    ("PIN.Ro", "pin.output_impedance_ohm", "Ohm", "4.9"),
    ("PIN.Isol", "pin.solar_current_a", "A", "4.9"),
    ("PIN.Ibgd", "pin.background_current_a", "A", "4.9"),
    ("PIN.Ilkg", "pin.leakage_current_a", "A", "4.9"),
    ("PIN.Nep", "pin.nep_w_per_rthz", "W/rtHz", "4.9"),
    ("PIN.qe", "pin.quantum_efficiency", "-", "4.9"),
    ("PIN.Ztia", "pin.transimpedance_ohm", "V/A", "4.9"),
    # Table 4.11 - Parametric testing
    ("test.state", "sweep.enabled", "on | off", "4.11"),
    ("test.x_dep", "sweep.x_output", "outputs.NAME", "4.11"),
    ("test.y_dep", "sweep.y_output", "outputs.NAME", "4.11"),
    ("test.x_var", "sweep.vary", "Type.Name", "4.11"),
    ("test.x_start", "sweep.start", "-", "4.11"),
    ("test.x_stop", "sweep.stop", "-", "4.11"),
    ("test.n", "sweep.n", "integer", "4.11"),
    ("test.m", "sweep.repeat", "integer", "4.11"),
    ("test.i_scale", "sweep.scale", "lin | log", "4.11"),
    ("test.x_scale", "sweep.x_axis_scale", "lin | log", "4.11"),
    ("test.y_scale", "sweep.y_axis_scale", "lin | log", "4.11"),
)

THESIS_TO_KEY: dict[str, str] = {thesis: key for thesis, key, _, _ in THESIS_TABLE}

# Thesis output names that differ from Table 4.10 only by an older name (Table 4.11 uses CNR).
OUTPUT_ALIASES = {"CNR": "SNR"}


def resolve_key(name: str) -> str:
    """Project key for a thesis name or a project key (returned unchanged)."""
    return THESIS_TO_KEY.get(name, name)


def resolve_output(name: str) -> str:
    """Table 4.10 output name from ``outputs.Psig``, ``Psig`` or ``outputs.CNR``."""
    bare = name.split(".", 1)[1] if name.startswith("outputs.") else name
    return OUTPUT_ALIASES.get(bare, bare)
