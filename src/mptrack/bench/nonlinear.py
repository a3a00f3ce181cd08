"""Cost per measurement step of the nonlinear filters, in one run: the FEM grid filter, PF and UKF on
the Zhao 2013 eq. 42 example (standard Van der Pol variant, Q = 0.01·diag(10, 0.1)) (suite
"nonlinear"), and the EKF/UKF on the 4-state constant-velocity range-bearing model against FilterPy's
on the same inputs, plus the batch EKF in track-steps/s (suite "ekf-ukf")."""

from __future__ import annotations

import numpy as np

from ..models import NonlinearModel, constant_velocity, nonlinear_model, range_bearing
from ..continuous import ZHAO2013_X0, fem_filter, fem_profile, fem_steps, fem_substeps, simulate_sde, zhao2013_model
from ..nonlinear import ekf_filter, ekf_filter_batch, particle_filter, ukf_filter
from . import register_suite
from ._timing import best_time

__all__ = ["nonlinear_suite", "ekf_ukf_suite"]


@register_suite("nonlinear")
def nonlinear_suite(quick: bool) -> dict:
    steps = 10 if quick else 30
    repeats = 1 if quick else 3
    model = zhao2013_model(variant="vdp", diffusion_scale=0.01)
    _, z = simulate_sde(model, steps, np.random.default_rng(2013), ZHAO2013_X0)
    x0, P0 = np.array(ZHAO2013_X0), 0.1 * np.eye(2)
    rng = np.random.default_rng(1)
    box = ((-4.5, -4.5), (4.5, 4.5))
    cases = [
        ("UKF (compiled; RK4 moment equations, sub-steps by the drift's rate)", lambda: ukf_filter(model, z, x0, P0)),
        ("UKF, NumPy path, 20 fixed sub-steps (before)",
         lambda: ukf_filter(model, z, x0, P0, substeps=20, compiled=False)),
        ("PF, 200 particles (compiled, 2 RK4-split sub-steps)",
         lambda: particle_filter(model, z, x0, P0, rng, particles=200)),
        ("PF, 10^4 particles (compiled, 2 RK4-split sub-steps)",
         lambda: particle_filter(model, z, x0, P0, rng, particles=10_000)),
        ("PF, 10^4 particles, NumPy path (same numbers)",
         lambda: particle_filter(model, z, x0, P0, rng, particles=10_000, compiled=False)),
    ]
    rows = []
    base = best_time(lambda: z.copy(), repeats) / steps
    rows.append(["memory copy of z (baseline)", base * 1e3, None, None])
    for name, fn in cases:
        fn()
        t = best_time(fn, repeats) / steps
        rows.append([name, t * 1e3, None, None])
    for n in ((20, 40) if not quick else (20,)):
        rows += _fem_rows(model, z, x0, P0, n, box, repeats)
    notes = [
        "ms per measurement step (predict + update), best of the repeats; 'nodes' = FEM node count; "
        "'factorised %' = share of steps on which the default FEM filter factorised a new diffusion operator.",
        "FEM default (scheme='characteristics'): each second is 4 Strang steps, each a diffusion over tau/2, "
        "a transport along the drift's characteristics onto a grid placed around the density predicted for "
        "t + tau (moments, sigma points, box), and a diffusion over tau/2 there (the two half-steps between "
        "transports run as one); the update is Bayes' rule at the nodes after a search for separate posterior "
        "modes. The transport is compiled end to end: the grid's nodes are carried by RK4 steps of the flow, "
        "the quadrature points (36 per element, 4 on elements whose nodal values are all below 0.1 % of "
        "the largest) by the flow's serendipity interpolant, deposited on the new grid, then one "
        "band Cholesky solve with the mass matrix. The diffusion is SDIRK2 (2 single-precision band "
        "Cholesky solves per step) on factorisations kept across grids whose element sizes give a stage "
        "matrix within factors (0.8, 2) of theirs (a W-method); a new one is factorised when none is.",
        "'per step' rows: where a default step's time goes, in the run with the smallest total: the time "
        "in the predictions (one compiled call per second) split in proportion to the cost of their pieces, "
        "each timed alone on the run's own inputs (grid placement, carrying the density, diffusion steps; "
        "factorisations as their count times one's cost), the updates, and the rest (merging mixture "
        "parts, prior/posterior moments, the step records, Python); the rows add up to that run's total.",
        "scheme='sdirk2' is the Galerkin drift-diffusion operator (16 SDIRK2 sub-steps on 20x20, an LU "
        "factorisation whenever the grid moves); it loses the state at low diffusion (docs/nonlinear.md).",
        "PF: 2 Strang-split RK4 sub-steps per second (bias on this example ~0.003, a third of the Monte-Carlo "
        "error of 10^4 particles, docs/nonlinear.md); the compiled path costs the normal draws, 16 drift and 1 "
        "measurement evaluation per particle, weighting, moments and resampling.",
    ]
    return {"suite": "nonlinear", "title": "Nonlinear filters: cost per measurement step",
            "columns": ["filter", "ms per step", "nodes", "factorised %"], "rows": rows, "notes": notes}


# ---------------------------------------------------------------- EKF / UKF against FilterPy
_SENSOR = np.array([-50.0, 20.0])
_R_BR = np.diag([np.radians(1.0) ** 2, 4.0])                    # bearing rad², range m²
_X0, _P0 = np.array([100.0, 8.0, 150.0, -3.0]), np.diag([50.0, 5.0, 50.0, 5.0])


def _range_bearing_data(steps: int, tracks: int, seed: int = 15):
    """The CV range-bearing model and z (tracks, steps, 2) of tracks simulated from x0 (noisy)."""
    model = nonlinear_model(constant_velocity(1.0, 0.5, axes=2), range_bearing(_SENSOR, _R_BR))
    rng = np.random.default_rng(seed)
    F, LQ, LR = np.asarray(model.jac_f(_X0)), np.linalg.cholesky(model.Q), np.linalg.cholesky(_R_BR)
    x = np.broadcast_to(_X0, (tracks, 4)).copy()
    z = np.empty((tracks, steps, 2))
    for k in range(steps):
        x = x @ F.T + rng.standard_normal((tracks, 4)) @ LQ.T
        z[:, k] = model.h(x) + rng.standard_normal((tracks, 2)) @ LR.T
    z[:, :, 0] = (z[:, :, 0] + np.pi) % (2.0 * np.pi) - np.pi
    return model, z


def _hx(x):
    dx, dy = x[0] - _SENSOR[0], x[2] - _SENSOR[1]
    return np.array([np.arctan2(dy, dx), np.hypot(dx, dy)])


def _jac(x):
    dx, dy = x[0] - _SENSOR[0], x[2] - _SENSOR[1]
    r2 = dx * dx + dy * dy
    r = np.sqrt(r2)
    return np.array([[-dy / r2, 0.0, dx / r2, 0.0], [dx / r, 0.0, dy / r, 0.0]])


def _residual(a, b):
    d = a - b
    d[0] = (d[0] + np.pi) % (2.0 * np.pi) - np.pi
    return d


def _filterpy_ekf(model, z):
    """FilterPy's ExtendedKalmanFilter (Joseph form, as ours) with plain NumPy h, Jacobian and residual."""
    from filterpy.kalman import ExtendedKalmanFilter
    ekf = ExtendedKalmanFilter(4, 2)
    ekf.x, ekf.P, ekf.F, ekf.Q, ekf.R = _X0.copy(), _P0.copy(), np.array(model.jac_f(_X0)), np.array(model.Q), _R_BR
    xs = np.empty((len(z), 4))
    for k, zk in enumerate(z):
        ekf.predict()
        ekf.update(zk, HJacobian=_jac, Hx=_hx, residual=_residual)
        xs[k] = ekf.x
    return xs


def _user_model(model) -> NonlinearModel:
    """The range-bearing model as a user writes it: f, h in NumPy (vectorised over states) and FilterPy's
    analytic Jacobian of one state (jac_h = _jac)."""
    F = np.array(model.jac_f(_X0))
    Ft = F.T.copy()

    def f(X):
        return X @ Ft

    def h(X):
        dx, dy = X[..., 0] - _SENSOR[0], X[..., 2] - _SENSOR[1]
        return np.stack([np.arctan2(dy, dx), np.hypot(dx, dy)], axis=-1)
    return NonlinearModel(f, h, np.array(model.Q), _R_BR, jac_f=lambda x: F, jac_h=_jac, angle_components=(0,))


def _filterpy_ukf(model, z, ut):
    """FilterPy's UnscentedKalmanFilter (Merwe points), predict()/update() per step; its predict() draws
    the update's sigma points from the prediction, as ours does (the same numbers)."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
    F = np.array(model.jac_f(_X0))
    points = MerweScaledSigmaPoints(4, **ut)
    ukf = UnscentedKalmanFilter(4, 2, 1.0, fx=lambda x, dt: F @ x, hx=_hx, points=points, residual_z=_residual,
                                z_mean_fn=lambda Z, Wm: np.array([np.arctan2(Wm @ np.sin(Z[:, 0]),
                                                                             Wm @ np.cos(Z[:, 0])), Wm @ Z[:, 1]]))
    ukf.x, ukf.P, ukf.Q, ukf.R = _X0.copy(), _P0.copy(), np.array(model.Q), _R_BR
    xs = np.empty((len(z), 4))
    for k, zk in enumerate(z):
        ukf.predict()
        ukf.update(zk)
        xs[k] = ukf.x
    return xs


def _rel(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _fem_rows(model, z, x0, P0, n: int, box, repeats: int) -> list:
    """The FEM rows of an n x n grid: the default on a moving grid and on a fixed box, scheme='sdirk2'
    (20 x 20 only), and where a default step's time goes (fem_profile): the default's row and its parts are
    one run's, so they add up under any load."""
    steps, grid = z.shape[0], (n, n)
    default = list(fem_steps(model, z, x0, P0, grid=grid))
    nodes = default[0].prior.parts[0][1].grid.size
    share = round(100.0 * np.mean([s.factorised for s in default]))
    variants = [("moving grid (the default: characteristics, 4 Strang steps per second)", {}, share),
                ("fixed box (characteristics)", {"box": box}, None)]
    if n == 20:
        variants.append((f"moving grid, scheme='sdirk2' ({fem_substeps(grid)} SDIRK2 sub-steps, an LU "
                         "per move)", {"scheme": "sdirk2"}, None))
    parts = fem_profile(model, z, x0, P0, grid=grid, repeats=repeats)
    rows = []
    for label, options, pct in variants:
        if options:
            t = best_time(lambda o=options: fem_filter(model, z, x0, P0, grid=grid, **o), repeats) / steps
        else:                       # the default's time is the profile's best run, the one its parts split
            t = sum(parts.values())
        rows.append([f"FEM {n}x{n}, {label}", t * 1e3, nodes, pct])
    for label, t in parts.items():
        rows.append([f"FEM {n}x{n} default, per step: {label}", t * 1e3, nodes, None])
    return rows


@register_suite("ekf-ukf")
def ekf_ukf_suite(quick: bool) -> dict:
    import dataclasses
    steps = 200 if quick else 1000
    tracks, batch_steps = (200, 100) if quick else (1000, 1000)
    repeats = 2 if quick else 5
    model, zz = _range_bearing_data(steps, 1)
    z = zz[0]
    untagged = dataclasses.replace(model)                       # the same model untagged: the generic path
    user = _user_model(model)
    numeric = dataclasses.replace(user, jac_f=None, jac_h=None)
    ut = {"alpha": 0.5, "beta": 2.0, "kappa": -1.0}
    rows = []

    def per_step(fn):
        fn()
        return best_time(fn, repeats) / steps * 1e6

    try:
        import filterpy  # noqa: F401
        fp_ekf = per_step(lambda: _filterpy_ekf(model, z))
        fp_ukf = per_step(lambda: _filterpy_ukf(model, z, ut))
        fp_x = {"EKF": _filterpy_ekf(model, z), "UKF": _filterpy_ukf(model, z, ut)}
    except ImportError:
        fp_ekf = fp_ukf = fp_x = None

    def diff(method, res):
        return None if fp_x is None else _rel(res.x, fp_x[method])
    for method, run, peer in (("EKF", lambda m: ekf_filter(m, z, _X0, _P0), fp_ekf),
                              ("UKF", lambda m: ukf_filter(m, z, _X0, _P0, **ut), fp_ukf)):
        cases = [("compiled (named model)", model),
                 ("generic path, user f, h and analytic Jacobians (FilterPy's)", user),
                 ("generic path, the named model untagged", untagged)]
        if method == "EKF":
            cases.append(("generic path, user f, h, finite-difference Jacobians", numeric))
        for label, mdl in cases:
            t = per_step(lambda mdl=mdl: run(mdl))
            rows.append([f"{method}, {label}", t, peer, None if peer is None else peer / t, 1e6 / t,
                         diff(method, run(mdl))])
    _, zb = _range_bearing_data(batch_steps, tracks, seed=16)
    ekf_filter_batch(model, zb[:2, :2], _X0, _P0)
    t = best_time(lambda: ekf_filter_batch(model, zb, _X0, _P0), max(1, repeats // 2)) / (tracks * batch_steps)
    check = ekf_filter_batch(model, zb[:3], _X0, _P0)
    batch_diff = max(_rel(check.x[b], ekf_filter(untagged, zb[b], _X0, _P0).x) for b in range(3))
    rows.append([f"batch EKF, compiled, {tracks} tracks x {batch_steps} steps", t * 1e6, None, None, 1.0 / t,
                 batch_diff])
    small = zb[:, : max(10, batch_steps // 20)]
    t = best_time(lambda: ekf_filter_batch(untagged, small, _X0, _P0), 1) / small[:, :, 0].size
    rows.append([f"batch EKF, NumPy path, {tracks} tracks x {small.shape[1]} steps", t * 1e6, None, None, 1.0 / t,
                 None])
    notes = [
        "4-state constant-velocity model [x, vx, y, vy] (q = 0.5 m²/s³, dt = 1 s) seen in bearing and range "
        "from one sensor (σ = 1°, 2 m); every filter runs on the same simulated measurements in the same run. "
        "µs per step = best of the repeats over a whole single-track run (validation included).",
        "FilterPy: ExtendedKalmanFilter (Joseph form) and UnscentedKalmanFilter (Merwe points, α = 0.5, "
        "β = 2, κ = -1), predict()/update() per step with plain NumPy h, Jacobian, residual and circular mean. "
        "'x FilterPy' = FilterPy's time / ours in the same run; 'max rel. diff' = max |x - x_FilterPy| / "
        "max |x_FilterPy| (FilterPy's UKF draws the update's sigma points from the prediction, as ours); for "
        "the batch row, against the generic-path ekf_filter per track.",
        "Compiled = mptrack.nonlinear._named_kernels, used automatically for nonlinear_model(linear motion, "
        "named measurement model). Generic path = any NonlinearModel: the user's f, h, Jacobians, Q, R "
        "evaluated in Python once per step (the UKF: f and h on all sigma points at once), the matrix "
        "arithmetic in the compiled step kernels (mptrack.nonlinear._step_kernels). 'User f, h' = the "
        "functions a user writes (FilterPy's Jacobian); 'the named model untagged' = the constructors' "
        "vectorised h and Jacobians.",
    ]
    return {"suite": "ekf-ukf", "title": "EKF/UKF per step against FilterPy; batch EKF throughput",
            "columns": ["filter", "us per step", "FilterPy us per step", "x FilterPy", "track-steps/s",
                        "max rel. diff"],
            "rows": rows, "notes": notes}
