"""Analysis of simulated results: sensitivity, (later) coverage and accuracy against time."""

from .sensitivity import sensitivity_at

__all__ = ["sensitivity_at"]
