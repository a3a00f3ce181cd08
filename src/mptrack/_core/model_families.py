"""Model types of other packages that the generic filters of mptrack.nonlinear take, each with the code
that runs those filters on it.

mptrack.nonlinear's UKF and particle filter are written for its discrete-time
:class:`mptrack.models.NonlinearModel`; a package that defines another kind of model registers it here when
it is imported (mptrack.continuous: :class:`ContinuousDiscreteModel`, the UKF on the moment equations and
the particles following the SDE).  So that package depends on mptrack.nonlinear and not the other way round,
and a filter finds the model's family by its type (a registry, not an if/elif on types it would have to
import).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

__all__ = ["ModelFamily", "register_family", "family_kinds", "model_family"]


@dataclass(frozen=True)
class ModelFamily:
    """How the generic filters run on models of type ``kind``.

    ukf(model, z, x0, P0, *, substeps, ut, prior, compiled) -> FilterResult
        the UKF from validated arguments (``substeps`` None: the family's choice; ``ut`` the unscented
        parameters)
    pf(model, rng, *, substeps, scheme, compiled) -> (propagate(X, k), log_likelihood(zk, X, k))
        the particle filter's moves and weights (``substeps`` None: the family's default; it validates
        ``scheme`` and ``compiled``)
    """

    kind: type
    ukf: Callable
    pf: Callable


_FAMILIES: dict[type, ModelFamily] = {}


def register_family(family: ModelFamily) -> None:
    _FAMILIES[family.kind] = family


def family_kinds() -> tuple[type, ...]:
    """The registered model types, in the order of registration."""
    return tuple(_FAMILIES)


def model_family(model) -> ModelFamily:
    """The family of ``model``'s type (the callers have checked it is one of :func:`family_kinds`)."""
    return next(f for kind, f in _FAMILIES.items() if isinstance(model, kind))
