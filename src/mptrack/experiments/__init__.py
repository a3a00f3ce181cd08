"""Paper reproductions: one module per paper, registered by key.

A module here registers its reproduction with :func:`register`; the CLI
(``mptrack reproduce KEY``) and the docs are generated from the registry.
"""

from ._registry import Experiment, RunContext, experiments, get_experiment, register, run_experiment
from ._results import Reproduction, Table, differences

__all__ = [
    "Experiment",
    "RunContext",
    "Reproduction",
    "Table",
    "differences",
    "experiments",
    "get_experiment",
    "register",
    "run_experiment",
]
