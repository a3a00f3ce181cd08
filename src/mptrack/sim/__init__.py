"""Simulators of trajectories and measurements."""

from ._linear import simulate_linear

__all__ = ["simulate_linear"]
