"""Reproduction of Assimakis & Adam (2014): 2-D tracking with KF/LF, steady-state and FIR filters."""

from ._assimakis import reproduce_assimakis
from ._registry import RunContext, register


@register("assimakis2014",
          paper="Assimakis & Adam (2014), Global Systems for Mobile Position Tracking Using Kalman and "
                "Lainiotis Filters",
          description="2-D models A/B, 12 implementations, burden Tables 2-4, FIR Tables 5-7, figures 1-2")
def run(ctx: RunContext):
    return reproduce_assimakis(ctx, key="assimakis2014", axes=2)
