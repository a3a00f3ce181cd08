"""Reproduction of Assimakis & Adam (2015): the 3-D version of Assimakis & Adam (2014)."""

from ._assimakis import reproduce_assimakis
from ._registry import RunContext, register


@register("assimakis2015",
          paper="Assimakis & Adam (2015), Mobile Position Tracking in Three Dimensions using Kalman and "
                "Lainiotis Filters",
          description="3-D models A/B, 12 implementations, burden Tables 2-3 and speedups, FIR (ours)")
def run(ctx: RunContext):
    return reproduce_assimakis(ctx, key="assimakis2015", axes=3)
