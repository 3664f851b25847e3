"""Spectrum processing (thesis FFT_peak.m) and PN correlation ranging."""

from .spectrum import PeakResult, analyze_records

__all__ = ["PeakResult", "analyze_records"]
