"""A high-accuracy reference posterior: the bootstrap particle filter with very many particles.

It shares nothing with the grid filter (Monte-Carlo sampling of the SDE
versus a Galerkin solution of the Fokker–Planck equation), so agreement
between the two is an independent check.  Its error on the conditional mean
is Monte-Carlo noise of order σ/√ESS: on eq. 42 (standard Van der Pol,
Q = 0.01·diag(10, 0.1), 30 s) two independent 2·10⁵-particle references
differ by about 0.002 RMS.  By default it takes 4× the particle filter's
sub-steps (8 RK4-split sub-steps per second on eq. 42 with Q × 0.01), whose
time-discretisation bias is far below that noise (:func:`pf_substep_study`).
"""

from __future__ import annotations

import numpy as np

from .._core.finiteness import finite_result
from .._core.validation import check_allocation, check_int
from ..errors import ParameterError
from ..result import FilterResult
from .._core.filter_inputs import prepare_nonlinear
from ..nonlinear import particle_filter
from ._model import ContinuousDiscreteModel
from ._pf import pf_substeps

__all__ = ["reference_filter", "pf_substep_study"]


@finite_result("the reference filter")
def reference_filter(model: ContinuousDiscreteModel, z, x0, P0, rng: np.random.Generator, *,
                     particles: int = 100_000, substeps: int | None = None,
                     scheme: str = "rk4-split") -> FilterResult:
    """A high-accuracy reference: the posterior means and covariances of a many-particle bootstrap PF.

    It shares no code path with the grid filter beyond the model, so FEM = reference is an independent
    check; its Monte-Carlo error is about sigma / sqrt(particles).

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped.
    x0 : array_like, shape (n,)
        The prior mean at time 0.
    P0 : array_like, shape (n, n)
        The prior covariance at time 0.
    rng : numpy.random.Generator
    particles : int, optional
    substeps : int, optional
        Sub-steps per dt (default 4 times the particle filter's default).
    scheme : {"rk4-split", "heun"}, optional

    Returns
    -------
    FilterResult
        Method "reference".

    References
    ----------
    .. [1] N. J. Gordon, D. J. Salmond and A. F. M. Smith, "Novel approach to nonlinear/non-Gaussian Bayesian
           state estimation", IEE Proceedings F, vol. 140, no. 2, pp. 107–113, 1993.
           doi:10.1049/ip-f-2.1993.0015
    """
    if substeps is None:
        substeps = 4 * pf_substeps(model, scheme)
    return particle_filter(model, z, x0, P0, rng, particles=particles, ess_threshold=0.5,
                           substeps=substeps, scheme=scheme, method="reference")


@finite_result("the sub-step study")
def pf_substep_study(model: ContinuousDiscreteModel, z, x0, P0, seed: int = 0, *, particles: int = 10_000,
                     runs: int = 12, substeps=(1, 2, 4, 5, 10, 20, 40), schemes=("heun", "rk4-split"),
                     ref_particles: int = 200_000, ref_runs: int = 2, ref_substeps: int = 40) -> dict:
    """Time-discretisation bias of the PF posterior mean against the sub-steps per dt (docs/nonlinear.md).

    The reference is the mean of ``ref_runs`` PFs with ``ref_particles`` particles and ``ref_substeps``
    Heun sub-steps.  For each scheme and sub-step count, ``runs`` PFs give the noise (RMS of one PF minus
    the reference) and the bias (RMS of the runs' mean minus the reference, with a Monte-Carlo resolution
    of about noise / sqrt(runs)).

    Parameters
    ----------
    model : ContinuousDiscreteModel
        The SDE model observed at discrete times.
    z : array_like, shape (T, m)
        Measurements; NaN components are skipped.
    x0 : array_like, shape (n,)
        The prior mean at time 0.
    P0 : array_like, shape (n, n)
        The prior covariance at time 0.
    seed : int, optional
        Root of the runs' random streams.
    particles, runs : int, optional
        Particles per PF and PFs per setting.
    substeps : sequence of int, optional
    schemes : sequence of str, optional
    ref_particles, ref_runs, ref_substeps : int, optional
        The reference's settings.

    Returns
    -------
    dict
        "rows": [[scheme, substeps, noise, bias, resolution], ...]; "reference_spread": the RMS difference
        of the first two references (None with one); "reference": the reference means (T, n).
    """
    z, x0, P0, _ = prepare_nonlinear(model, z, x0, P0, kinds=(ContinuousDiscreteModel,))
    seed = check_int("seed", seed, minimum=0)
    runs, ref_runs = check_int("runs", runs, minimum=1), check_int("ref_runs", ref_runs, minimum=1)
    for name, values in (("substeps", substeps), ("schemes", schemes)):
        if isinstance(values, (str, bytes)) or not np.iterable(values) or not len(values):
            raise ParameterError(f"{name}: expected a non-empty sequence, got {values!r}")
    substeps = tuple(check_int("substeps", s, minimum=1) for s in substeps)
    # every run's posterior means (T, n) are held, per scheme and sub-step count
    check_allocation("runs", runs, 8.0 * (ref_runs + runs) * z.shape[0] * model.n)
    seeds = np.random.SeedSequence(seed).spawn(ref_runs + runs)
    refs = [particle_filter(model, z, x0, P0, np.random.default_rng(seeds[i]), particles=ref_particles,
                            substeps=ref_substeps, scheme="heun").x for i in range(ref_runs)]
    ref = np.mean(refs, axis=0)
    spread = float(np.sqrt(np.mean((refs[0] - refs[1]) ** 2))) if ref_runs > 1 else None
    rows = []
    for scheme in schemes:
        for s in substeps:
            xs = np.array([particle_filter(model, z, x0, P0, np.random.default_rng(seeds[ref_runs + r]),
                                           particles=particles, substeps=s, scheme=scheme).x
                           for r in range(runs)])
            noise = float(np.sqrt(np.mean((xs - ref) ** 2)))
            bias = float(np.sqrt(np.mean((xs.mean(axis=0) - ref) ** 2)))
            rows.append([scheme, int(s), noise, bias, noise / np.sqrt(runs)])
    return {"rows": rows, "reference_spread": spread, "reference": ref}
