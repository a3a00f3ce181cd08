"""Zero-order Takagi–Sugeno inference on a grid of rules (Takagi & Sugeno 1985; Bouzera et al. 2017, eq. 13).

Rule (j1, ..., jp): IF x1 is A1[j1] AND ... AND xp is Ap[jp] THEN y = c[j1, ..., jp].
Firing strength = product of memberships (the paper's "degree of fulfilment");
output = sum(w c) / sum(w).  Inputs are clipped to each variable's universe of
discourse first, so a partition that covers its universe always fires a rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._core.validation import as_array, as_vector
from ..errors import ParameterError, ShapeError
from ._membership import MembershipFunction

__all__ = ["TakagiSugeno"]


@dataclass(frozen=True, eq=False)
class TakagiSugeno:
    """A zero-order TS system with a full rule grid.

    sets         per input variable, its fuzzy sets (tuple of MembershipFunction)
    consequents  array of shape (len(sets[0]), len(sets[1]), ...): the constant c of each rule
    universes    per input (lo, hi) to clip inputs to (None: no clipping)
    names        input names (for messages and display)

    References
    ----------
    .. [1] T. Takagi and M. Sugeno, "Fuzzy identification of systems and its applications to modeling and
           control", IEEE Transactions on Systems, Man, and Cybernetics, vol. SMC-15, no. 1, pp. 116–132, 1985.
           doi:10.1109/TSMC.1985.6313399
    """

    sets: tuple[tuple[MembershipFunction, ...], ...]
    consequents: np.ndarray
    universes: tuple[tuple[float, float] | None, ...] | None = None
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not _sequence(self.sets) or not all(_sequence(s) for s in self.sets):
            raise ParameterError(f"sets: expected one sequence of fuzzy sets per input, got {self.sets!r}")
        sets = tuple(tuple(s) for s in self.sets)
        if not sets or any(len(s) == 0 for s in sets):
            raise ParameterError("sets: every input needs at least one fuzzy set")
        for s in sets:
            for mf in s:
                if not isinstance(mf, MembershipFunction):
                    raise ParameterError(f"sets: expected MembershipFunction entries, got {type(mf).__name__}")
        shape = tuple(len(s) for s in sets)
        c = as_array("consequents", self.consequents, shape=shape).copy()
        c.setflags(write=False)
        universes = self.universes if self.universes is not None else (None,) * len(sets)
        if not _sequence(universes) or len(universes) != len(sets):
            raise ShapeError(f"universes: expected {len(sets)} entries ((lo, hi) or None), got {universes!r}")
        universes = tuple(None if u is None else _universe(u) for u in universes)
        names = self.names if self.names is not None else tuple(f"x{i + 1}" for i in range(len(sets)))
        if not _sequence(names) or len(names) != len(sets) or not all(isinstance(n, str) for n in names):
            raise ParameterError(f"names: expected {len(sets)} input names, got {names!r}")
        object.__setattr__(self, "sets", sets)
        object.__setattr__(self, "consequents", c)
        object.__setattr__(self, "universes", tuple(universes))
        object.__setattr__(self, "names", tuple(names))

    @property
    def n_inputs(self) -> int:
        return len(self.sets)

    def memberships(self, i: int, x) -> np.ndarray:
        """Memberships (..., len(sets[i])) of input ``i`` at values x (clipped to its universe)."""
        x = as_array(f"x ({self.names[i]})", x)
        if self.universes[i] is not None:
            x = np.clip(x, *self.universes[i])
        return np.stack([mf(x) for mf in self.sets[i]], axis=-1)

    def firing(self, *inputs) -> np.ndarray:
        """Rule firing strengths (..., n1, n2, ...) = product of the inputs' memberships."""
        if len(inputs) != self.n_inputs:
            raise ShapeError(f"inputs: expected {self.n_inputs} ({', '.join(self.names)}), got {len(inputs)}")
        arrays = [as_array(f"inputs[{i}] ({name})", x) for i, (name, x) in enumerate(zip(self.names, inputs))]
        arrays = np.broadcast_arrays(*arrays)
        w = None
        for i, x in enumerate(arrays):
            mu = self.memberships(i, x)
            w = mu if w is None else w[..., None] * mu.reshape(mu.shape[:-1] + (1,) * (w.ndim - mu.ndim + 1)
                                                                 + mu.shape[-1:])
        return w

    def __call__(self, *inputs):
        """The TS output sum(w c)/sum(w) (eq. 13) for broadcast arrays of inputs."""
        w = self.firing(*inputs)
        axes = tuple(range(-self.n_inputs, 0))
        total = w.sum(axis=axes)
        if np.any(total <= 0):
            raise ParameterError(f"inputs: no rule fires for some inputs of ({', '.join(self.names)}); "
                                 "widen the fuzzy sets or give universes to clip to")
        out = (w * self.consequents).sum(axis=axes) / total
        return out[()] if out.ndim == 0 else out


def _sequence(value) -> bool:
    return isinstance(value, (tuple, list))


def _universe(value) -> tuple[float, float]:
    lo, hi = as_vector("universes", value, 2)
    if not lo <= hi:
        raise ParameterError(f"universes: expected (lo, hi) with lo <= hi, got {tuple(value)!r}")
    return float(lo), float(hi)
