"""Simulators of trajectories and measurements."""

from ._linear import simulate_linear
from ._network import network_scans, simulate_network

__all__ = ["simulate_linear", "simulate_network", "network_scans"]
