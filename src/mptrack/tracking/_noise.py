"""Automatic noise calibration: maximum-likelihood fix noise and process noise for each track.

Model.  Fix k of track b has variance ``c_b w_k`` per axis: w_k = accuracy_k^2
where the input gives an accuracy (then sqrt(c_b) is the factor by which the
device under- or over-states it), else w_k = 1 (then c_b = sigma_b^2).  The
motion is the model's integrator chain with white-noise density q_b.

Likelihood.  The Gaussian log-likelihood of the innovations of the accepted
fixes, conditional on the first ``order`` fixes of each stretch (a diffuse
start: :func:`._likelihood.loglik_tracks`), so it depends on the data and (c, q)
only, not on a prior.  R and Q are both proportional to c at a fixed ratio
lambda = q/c, so for fixed lambda the maximising c is E/N (NIS sum over its
count, at c = 1) and the scale is concentrated out (Harvey 1989, sec. 3.4):
the search is one-dimensional, over ln lambda.  With ``sigma_m`` or ``q``
given, the other parameter is searched alone on the full likelihood.

Search.  A grid of decades (+-4) around a method-of-moments start
(:func:`._likelihood.moment_guess`), widened while the best point is at its edge,
then golden-section search to 0.01 in ln lambda; all groups in lockstep, each
step one compiled pass over the tracks.  Later rounds start from the last
estimate (+-half a decade).

Outliers.  Round 1 leaves out isolated spikes (:func:`_spike_mask`).  Each
round then runs the gated filter with the current estimates (round 1's at a
robust scale, :func:`_robust_scale`), leaves out the fixes it rejects and its
manoeuvre candidates, restarts the likelihood at its restarts, and estimates
again, until the accepted fixes stop changing (at most ``MAX_ROUNDS`` rounds).

Standard errors.  The observed information of (ln c, ln q): central second
differences of the log-likelihood, step 0.1 (for a sigma held at its floor,
the standard error of ln q given it).

Pooling and fallbacks.  A track keeps its own estimate when it has at least
``MIN_FIXES`` fixes and its estimate is determined (standard error of
ln sigma <= ``MAX_SE_LN_SIGMA`` and of ln q <= ``MAX_SE_LN_Q``, on the first
round); the other tracks take the pooled estimate of all tracks of the table
(grouped by whether they have accuracies).  A pool with fewer than
``MIN_POOLED_DOF`` innovations, and a track whose fixes are all one point or
one exact line, fall back to the stated defaults.  An estimated fix noise that
collapses towards 0 (receivers that smooth their output) is held at 1 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._columns import FixTable, median_by
from ._engine import filter_tracks
from ._track_filter import INIT, MANOEUVRE, OUTLIER, RESET
from ._likelihood import RESTART, SKIP, USE, loglik_tracks, moment_guess
from ._registry import DEFAULT_SIGMA_M

__all__ = ["NoiseSpec", "NoiseEstimate", "SOURCES", "fix_weights", "estimate_noise", "MIN_FIXES", "SIGMA_FLOOR_M"]

#: How a track's parameter was set (the ``*_source`` columns of the track summary).
SOURCES = ("estimated", "pooled", "default", "given")
ESTIMATED, POOLED, DEFAULT, GIVEN = range(4)
MIN_FIXES = 30
MIN_POOLED_DOF = 40
MAX_SE_LN_SIGMA = 0.3   # a track's own estimate is used when sigma is known to ~30 %
MAX_SE_LN_Q = 0.7       # and q to a factor of ~2; otherwise the pooled estimate
MAX_ROUNDS = 4
SCOPES = ("track", "file")
_DECADE = math.log(10.0)
_GOLD = (math.sqrt(5.0) - 1.0) / 2.0
_TOL = 0.01
_H = 0.1
_LOG2PI = math.log(2.0 * math.pi)
# search bounds: ln lambda (1/s^3 for cv), ln q, ln c
_BOUNDS = {"ratio": (math.log(1e-16), math.log(1e8)), "q": (math.log(1e-12), math.log(1e8)),
           "c": (math.log(1e-8), math.log(1e12))}
SIGMA_FLOOR_M = 1e-3   # the smallest fix noise an estimate may take (m)
_C_FLOOR = SIGMA_FLOOR_M ** 2


@dataclass(frozen=True)
class NoiseSpec:
    """What to estimate and how (see the module doc).

    order       states per axis of the motion model (2 cv, 3 ca)
    prior       (order,) prior variances of the derivatives at a track's start (entry 0 unused)
    sigma_m     given fix noise (m, 1-sigma per axis) where a fix has no accuracy; None: estimate
    q           given process-noise density; None: estimate
    scope       "track": one estimate per track (short tracks pooled); "file": one for all tracks
                (one of SCOPES; checked where the user gives it, TrackOptions)
    gate        NIS gate of the outlier rounds (inf: none); max_rej as in the filter
    max_gap_s   a gap longer than this starts a new stretch of the likelihood (a new segment of the track)
    default_sigma_m, default_q   the fallbacks for tracks that cannot be calibrated
    """

    order: int
    prior: np.ndarray
    sigma_m: float | None = None
    q: float | None = None
    scope: str = "track"
    gate: float = math.inf
    max_rej: int = 3
    max_gap_s: float = math.inf
    default_sigma_m: float = DEFAULT_SIGMA_M
    default_q: float = 2.0


@dataclass(frozen=True, eq=False)
class NoiseEstimate:
    """Per-track noise parameters: fix variance factor ``c`` (fix k has variance c w_k), process-noise
    density ``q``, standard errors of ln c and ln q (NaN where not estimated), how each was set
    (index into SOURCES), and the pooled estimates made."""

    c: np.ndarray
    q: np.ndarray
    se_log_c: np.ndarray
    se_log_q: np.ndarray
    source_c: np.ndarray
    source_q: np.ndarray
    pooled: dict  # has-accuracy kind -> (c, q, se ln c, se ln q) of its pooled estimate, if any


def fix_weights(table: FixTable, sigma_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(w (N,), has_accuracy (B,)): the unit fix variances of every row.

    With ``sigma_m`` given, w = accuracy^2 where a fix has one, else sigma_m^2 (and c = 1).
    Without it, w = accuracy^2, a fix without one takes its track's median accuracy, and a
    track with none has w = 1 (then c is sigma^2).
    """
    acc = table.accuracy
    if acc is None:
        acc = np.full(table.N, np.nan)
    good = np.isfinite(acc) & (acc > 0)
    w = np.where(good, acc * acc, np.nan)
    has = np.add.reduceat(good.astype(np.int64), table.offsets[:-1]) > 0 if table.N else np.zeros(0, bool)
    has &= table.counts > 0
    if sigma_m is not None:
        return np.where(good, w, float(sigma_m) ** 2), has
    if not good.all():
        fill = np.where(has, table.per_track_median(w, good), 1.0)
        w = np.where(good, w, table.per_row(fill))
    return w, has


class _Problem:
    """The likelihood of one table as a function of per-group search coordinates."""

    def __init__(self, table: FixTable, w: np.ndarray, spec: NoiseSpec, group: np.ndarray, n_groups: int) -> None:
        self.table, self.w, self.spec = table, w, spec
        self.group, self.G = group, n_groups
        self.mask = np.zeros(table.N, dtype=np.int8)
        self.mode = "ratio" if spec.sigma_m is None and spec.q is None else ("q" if spec.q is None else "c")

    def typical_w(self, groups: np.ndarray) -> np.ndarray:
        """The median unit fix variance over the rows of each group (1 for an empty one)."""
        med = median_by(self.table.per_row(self.group), self.w, groups)
        return np.where(np.isnan(med), 1.0, med)

    def params(self, groups: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(active tracks, c, q) of the tracks of ``groups`` at search coordinates ``theta``."""
        th = np.full(self.G, np.nan)
        th[groups] = theta
        tb = th[np.maximum(self.group, 0)]
        active = np.isin(self.group, groups) & (self.group >= 0)
        if self.mode in ("ratio", "q"):  # "q": sigma given, w carries it and c is 1
            c, q = np.ones(self.table.B), np.exp(tb)
        else:
            c, q = np.exp(tb), np.full(self.table.B, float(self.spec.q))
        return active, c, np.where(active, q, 1.0)

    def pieces(self, groups: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """(len(groups), 3) sums of (E, L, N) of each group at ``theta``."""
        tab = self.table
        active, c, q = self.params(groups, theta)
        out = np.zeros((tab.B, 3))
        loglik_tracks(tab.offsets, active, tab.t, tab.east, tab.north, self.w, self.mask, c, q,
                      self.spec.order, out)
        gid = np.where(active, self.group, self.G)
        sums = np.stack([np.bincount(gid, weights=out[:, j], minlength=self.G + 1)[:self.G] for j in range(3)], 1)
        return sums[groups]

    def loglik(self, groups: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """The (concentrated, in mode "ratio") log-likelihood of each group at ``theta``."""
        E, L, N = self.pieces(groups, theta).T
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.mode == "ratio":
                ll = -0.5 * (N * np.log(E / N) + L + N * (1.0 + _LOG2PI))
            else:
                ll = -0.5 * (E + L + N * _LOG2PI)
        return np.where((N > 0) & np.isfinite(ll), ll, -np.inf)


def _maximise(problem: _Problem, groups: np.ndarray, theta0: np.ndarray, half: float, step: float) -> np.ndarray:
    """The maximiser of each group's log-likelihood: grid of ``step`` around theta0 (+- half, widened
    while the best point is at an edge, up to the bounds: a poor start must not end the search at
    the grid's edge), then golden-section search between the grid neighbours."""
    lo, hi = _BOUNDS[problem.mode]
    theta0 = np.clip(theta0, lo, hi)
    offs = np.arange(-half, half + step / 2, step)
    grid = np.clip(theta0[:, None] + offs[None, :], lo, hi)
    vals = np.stack([problem.loglik(groups, grid[:, j]) for j in range(grid.shape[1])], axis=1)
    for _ in range(int(math.ceil((hi - lo) / step))):  # widen until the best point is inside (or at a bound)
        best = np.argmax(vals, axis=1)
        left = (best == 0) & (grid[:, 0] > lo)
        right = (best == grid.shape[1] - 1) & (grid[:, -1] < hi)
        if not (left.any() or right.any()):
            break
        new_l = np.clip(grid[:, 0] - step, lo, hi)
        new_r = np.clip(grid[:, -1] + step, lo, hi)
        val_l = np.full(len(groups), -np.inf)
        val_r = np.full(len(groups), -np.inf)
        if left.any():
            val_l[left] = problem.loglik(groups[left], new_l[left])
        if right.any():
            val_r[right] = problem.loglik(groups[right], new_r[right])
        grid = np.column_stack([np.where(left, new_l, grid[:, 0]), grid, np.where(right, new_r, grid[:, -1])])
        vals = np.column_stack([val_l, vals, val_r])
    best = np.argmax(vals, axis=1)
    rows = np.arange(len(groups))
    a = np.clip(grid[rows, best] - step, lo, hi)
    b = np.clip(grid[rows, best] + step, lo, hi)
    x1 = b - _GOLD * (b - a)
    x2 = a + _GOLD * (b - a)
    f1 = problem.loglik(groups, x1)
    f2 = problem.loglik(groups, x2)
    for _ in range(int(math.ceil(math.log(_TOL / (2 * step)) / math.log(_GOLD)))):
        left = f1 >= f2                  # the maximum lies in [a, x2]
        b = np.where(left, x2, b)
        a = np.where(left, a, x1)
        x_new = np.where(left, b - _GOLD * (b - a), a + _GOLD * (b - a))
        f_new = problem.loglik(groups, x_new)
        x1, x2, f1, f2 = (np.where(left, x_new, x2), np.where(left, x1, x_new),
                          np.where(left, f_new, f2), np.where(left, f1, f_new))
    theta = np.where(f1 >= f2, x1, x2)
    fbest = np.maximum(f1, f2)
    # a grid point can beat the bracket's interior only at a bound (a flat or monotone likelihood)
    gbest = vals[rows, best]
    return np.where(gbest > fbest, grid[rows, best], theta)


def _start(problem: _Problem, groups: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """Search coordinates of the method-of-moments start of each group (median over its tracks)."""
    tab = problem.table
    c, q = guess[:, 0], guess[:, 1]
    if problem.mode == "ratio":
        x = np.log(q / c)
    elif problem.mode == "q":
        x = np.log(q)
    else:
        x = np.log(c)
    default = {"ratio": math.log(2.0 / 25.0), "q": math.log(problem.spec.default_q),
               "c": math.log(problem.spec.default_sigma_m ** 2)}[problem.mode]
    med = median_by(problem.group, x, groups, np.isfinite(x) & (tab.counts > 2))
    return np.where(np.isnan(med), default, med)


def _resolve(problem: _Problem, groups: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c, q, N) of each group at its optimum ``theta``."""
    E, L, N = problem.pieces(groups, theta).T
    if problem.mode == "ratio":
        with np.errstate(divide="ignore", invalid="ignore"):
            c = E / N
        return c, c * np.exp(theta), N
    if problem.mode == "q":  # c is 1 for every track when sigma is given (w carries it)
        return np.ones(len(groups)), np.exp(theta), N
    return np.exp(theta), np.full(len(groups), float(problem.spec.q)), N


def _standard_errors(problem: _Problem, groups: np.ndarray, c: np.ndarray, q: np.ndarray, floored: np.ndarray):
    """(se ln c, se ln q) of each group from the observed information (central differences); a
    group whose c was held at its floor (not a maximum in c) gets the se of ln q given c."""
    h = _H
    u, v = np.log(c), np.log(q)
    nan = np.full(len(groups), np.nan)
    if problem.mode == "ratio":
        lam = v - u
        runs = {k: problem.pieces(groups, lam + k * h) for k in (-2, -1, 0, 1, 2)}

        def ll(du, dv):  # l(u + du h, v + dv h) from the unit-scale run at ln lambda + (dv - du) h
            E1, L1, N = runs[dv - du].T
            uu = u + du * h
            return -0.5 * (E1 * np.exp(-uu) + L1 + N * uu + N * _LOG2PI)

        f0 = ll(0, 0)
        huu = (ll(1, 0) - 2 * f0 + ll(-1, 0)) / h ** 2
        hvv = (ll(0, 1) - 2 * f0 + ll(0, -1)) / h ** 2
        huv = (ll(1, 1) - ll(1, -1) - ll(-1, 1) + ll(-1, -1)) / (4 * h ** 2)
        det = huu * hvv - huv ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            var_u, var_v = -hvv / det, -huu / det
            var_v_given_u = -1.0 / hvv
        ok = (huu < 0) & (det > 0)
        se_u = np.where(ok & ~floored, np.sqrt(np.abs(var_u)), np.nan)
        se_v = np.where(floored, np.where(hvv < 0, np.sqrt(np.abs(var_v_given_u)), np.nan),
                        np.where(ok, np.sqrt(np.abs(var_v)), np.nan))
        return se_u, se_v
    x = v if problem.mode == "q" else u
    f = [problem.loglik(groups, x + k * h) for k in (-1, 0, 1)]
    d2 = (f[0] - 2 * f[1] + f[2]) / h ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.where(d2 < 0, np.sqrt(-1.0 / d2), np.nan)
    return (nan, se) if problem.mode == "q" else (se, nan)


def _estimate(problem: _Problem, todo: np.ndarray, theta: np.ndarray, first: bool, est: dict,
              with_se: bool) -> None:
    """Search the groups ``todo`` of ``problem`` (from ``theta``, in place) and store their
    (c, q, N, floored, ok) in ``est`` (arrays over all groups), and their standard errors if
    ``with_se``.  The first search spans +-4 decades of the start (widened if needed); later ones,
    after the outlier mask changed a little, +-half a decade of the last estimate."""
    if not len(todo):
        return
    half, step = (4 * _DECADE, _DECADE) if first else (0.5 * _DECADE, 0.5 * _DECADE)
    theta[todo] = _maximise(problem, todo, theta[todo], half, step)
    c, q, n = _resolve(problem, todo, theta[todo])
    floor = _C_FLOOR / problem.typical_w(todo)
    ok = (n > 0) & np.isfinite(c) & (c > 0) & np.isfinite(q) & (q > 0)  # n = 0: no innovation to go by
    # a fix variance that collapses towards 0 (the motion explains every fix) is held at (1 mm)^2
    floored = ok & (c < floor) & (problem.mode != "q")
    c = np.where(floored, floor, c)
    for name, values in (("c", c), ("q", q), ("n", n), ("floored", floored), ("ok", ok)):
        est[name][todo] = values
    if with_se:
        _estimate_se(problem, todo, est)


def _estimate_se(problem: _Problem, todo: np.ndarray, est: dict) -> None:
    """Standard errors of the estimates of the groups ``todo`` (NaN where there is none)."""
    se_c, se_q = np.full(len(todo), np.nan), np.full(len(todo), np.nan)
    ok = est["ok"][todo]
    if ok.any():
        g = todo[ok]
        se_c[ok], se_q[ok] = _standard_errors(problem, g, est["c"][g], est["q"][g], est["floored"][g])
    est["se_c"][todo], est["se_q"][todo] = se_c, se_q


def _new_estimates(G: int) -> dict:
    return {"c": np.full(G, np.nan), "q": np.full(G, np.nan), "n": np.zeros(G), "se_c": np.full(G, np.nan),
            "se_q": np.full(G, np.nan), "floored": np.zeros(G, bool), "ok": np.zeros(G, bool)}


def _determined(est: dict, spec: NoiseSpec) -> np.ndarray:
    """Groups whose estimate is usable on its own: finite, and each estimated parameter known to
    within MAX_SE_LN_SIGMA (ln sigma) and MAX_SE_LN_Q (ln q)."""
    ok = est["ok"].copy()
    if spec.sigma_m is None:
        ok &= est["floored"] | (est["se_c"] / 2.0 <= MAX_SE_LN_SIGMA)
    if spec.q is None:
        ok &= est["se_q"] <= MAX_SE_LN_Q
    return ok


def estimate_noise(table: FixTable, w: np.ndarray, has_acc: np.ndarray, spec: NoiseSpec,
                   fixed: dict | None = None) -> NoiseEstimate:
    """Noise parameters of every track of ``table`` (see the module doc); ``w``, ``has_acc`` from
    :func:`fix_weights` with ``spec.sigma_m``.  ``fixed`` (an earlier table's ``pooled``) gives the
    tracks of a kind (with/without accuracies) that pooled estimate instead of a new one."""
    B = table.B
    fixed = fixed or {}
    default_c = np.where(has_acc, 1.0, spec.default_sigma_m ** 2)
    c = np.ones(B) if spec.sigma_m is not None else default_c
    q = np.full(B, spec.default_q if spec.q is None else float(spec.q))
    se_c, se_q = np.full(B, np.nan), np.full(B, np.nan)
    src_c = np.full(B, GIVEN if spec.sigma_m is not None else DEFAULT, dtype=np.int8)
    src_q = np.full(B, GIVEN if spec.q is not None else DEFAULT, dtype=np.int8)
    if spec.sigma_m is not None and spec.q is not None:
        return NoiseEstimate(c, q, se_c, se_q, src_c, src_q, {})
    for kind, (fc, fq, fsc, fsq) in fixed.items():
        sel = (has_acc == kind) & (table.counts >= 2)
        if spec.sigma_m is None:
            c[sel], se_c[sel], src_c[sel] = fc, fsc, POOLED
        if spec.q is None:
            q[sel], se_q[sel], src_q[sel] = fq, fsq, POOLED
    usable = (table.counts >= 2) & ~np.isin(has_acc, list(fixed))
    own = usable & (table.counts >= MIN_FIXES) if spec.scope == "track" else np.zeros(B, bool)
    own_group = np.where(own, np.cumsum(own) - 1, -1)
    kinds = [k for k in (False, True) if (usable & (has_acc == k)).any()]
    pool_group = np.where(usable, np.searchsorted(kinds, has_acc), -1) if kinds else np.full(B, -1)
    mine = _Problem(table, w, spec, own_group, int(own.sum()))
    pool = _Problem(table, w, spec, pool_group, len(kinds))
    mine.mask = pool.mask = np.where(_gap_starts(table, spec.max_gap_s), RESTART, _spike_mask(table, w)).astype(np.int8)
    guess = np.zeros((B, 3))
    moment_guess(table.offsets, table.t, table.east, table.north, w, mine.mask, guess)
    th_own, th_pool = _start(mine, np.arange(mine.G), guess), _start(pool, np.arange(pool.G), guess)
    e_own, e_pool = _new_estimates(mine.G), _new_estimates(pool.G)
    todo = np.arange(mine.G)
    row_track = np.repeat(np.arange(B), table.counts)
    for rounds in range(1, MAX_ROUNDS + 1):
        # which tracks carry their own estimate is decided on the first round's standard errors
        _estimate(mine, todo, th_own, rounds == 1, e_own, with_se=rounds == 1)
        if rounds == 1:
            alone = np.zeros(B, bool)
            alone[own] = _determined(e_own, spec)[own_group[own]]
            needs_pool = usable & ~alone
            pool_todo = np.unique(pool_group[needs_pool])
        _estimate(pool, pool_todo, th_pool, rounds == 1, e_pool, with_se=False)
        c_b, q_b, how = _assign(spec, c, q, alone, own_group, e_own, needs_pool, pool_group, e_pool)
        if not math.isfinite(spec.gate):
            break
        # outliers inflate the Gaussian estimate: the first gating runs at a robust scale
        c_g, q_g = _robust_scale(table, w, c_b, q_b, how, spec) if rounds == 1 else (c_b, q_b)
        mask = _gated_mask(table, w, c_g, q_g, spec)
        changed = mask != mine.mask
        mine.mask = pool.mask = mask
        if not changed.any():
            break
        moved = np.zeros(B, bool)
        moved[row_track[changed]] = True
        todo = np.unique(own_group[moved & own])
        # a pool is re-estimated when any of its members moved and some track still needs it
        needed = np.unique(pool_group[needs_pool])
        pool_todo = np.intersect1d(np.unique(pool_group[moved & usable]), needed)
    if rounds > 1:  # the standard errors at the final estimates
        _estimate_se(mine, np.unique(own_group[alone]), e_own)
    _estimate_se(pool, np.unique(pool_group[needs_pool]), e_pool)
    for src, e, g in ((ESTIMATED, e_own, own_group), (POOLED, e_pool, pool_group)):
        sel = how == src
        if spec.sigma_m is None:
            se_c[sel], src_c[sel] = e["se_c"][g[sel]], src
        if spec.q is None:
            se_q[sel], src_q[sel] = e["se_q"][g[sel]], src
    found = {kind: (float(e_pool["c"][i]), float(e_pool["q"][i]), float(e_pool["se_c"][i]), float(e_pool["se_q"][i]))
             for i, kind in enumerate(kinds) if _pool_usable(e_pool, i)}
    return NoiseEstimate(c_b, q_b, se_c, se_q, src_c, src_q, found)


def _pool_usable(e_pool: dict, i: int) -> bool:
    return bool(e_pool["ok"][i] and e_pool["n"][i] >= MIN_POOLED_DOF)


def _assign(spec, c, q, alone, own_group, e_own, needs_pool, pool_group, e_pool):
    """Per-track (c, q) and how each was set: its own estimate, the pooled one, or the default."""
    c_b, q_b = c.copy(), q.copy()
    how = np.full(len(c), DEFAULT, dtype=np.int8)
    usable = np.array([_pool_usable(e_pool, i) for i in range(len(e_pool["ok"]))] + [False], bool)
    pooled = needs_pool & usable[pool_group]   # pool_group -1 (no pool) picks the trailing False
    for sel, e, g, src in ((alone, e_own, own_group, ESTIMATED), (pooled, e_pool, pool_group, POOLED)):
        if spec.sigma_m is None:
            c_b[sel] = e["c"][g[sel]]
        if spec.q is None:
            q_b[sel] = e["q"][g[sel]]
        how[sel] = src
    return c_b, q_b, how


#: The median of chi-square with 2 degrees of freedom (2 ln 2): the median NIS of a consistent filter.
_MEDIAN_NIS = 2 * math.log(2)
#: A spike is this many times its track's median squared residual (chi-square 2 dof: 0.9999 over the median).
SPIKE_FACTOR = -2 * math.log(1e-4) / _MEDIAN_NIS


def _spike_mask(table: FixTable, w: np.ndarray) -> np.ndarray:
    """The first round's likelihood mask: isolated spikes left out.

    A fix's residual from the straight line (in time) between its two neighbours, over its unit
    variance, is a spike when it is a local maximum and above ``SPIKE_FACTOR`` times its
    track's median: a model-free screen, so that a few gross outliers cannot pull the Gaussian
    first estimate up (the later rounds judge every fix again with the gated filter)."""
    N = table.N
    mask = np.zeros(N, dtype=np.int8)
    if N < 3:
        return mask
    t, e, n = table.t, table.east, table.north
    inner = np.ones(N, bool)
    inner[table.offsets[:-1][table.counts > 0]] = False
    inner[(table.offsets[1:] - 1)[table.counts > 0]] = False
    k = np.flatnonzero(inner)
    span = t[k + 1] - t[k - 1]
    a = np.divide(t[k] - t[k - 1], span, out=np.full(len(k), 0.5), where=span > 0)
    re = e[k] - (e[k - 1] + a * (e[k + 1] - e[k - 1]))
    rn = n[k] - (n[k - 1] + a * (n[k + 1] - n[k - 1]))
    d2 = np.zeros(N)
    d2[k] = (re * re + rn * rn) / w[k]
    row_track = np.repeat(np.arange(table.B), table.counts)
    med = median_by(row_track, d2, np.arange(table.B), inner)
    with np.errstate(invalid="ignore"):
        peak = inner & (d2 > SPIKE_FACTOR * table.per_row(med)) & (d2 > np.r_[0, d2[:-1]]) & (d2 >= np.r_[d2[1:], 0])
    mask[peak] = SKIP
    return mask


def _gap_starts(table: FixTable, max_gap_s: float) -> np.ndarray:
    """(N,) the fixes that start a new segment: more than ``max_gap_s`` after the fix before in their track."""
    gap = np.zeros(table.N, dtype=bool)
    if table.N > 1:
        gap[1:] = np.diff(table.t) > max_gap_s
        gap[table.offsets[:-1][table.counts > 0]] = False
    return gap


def _white(table: FixTable, spec: NoiseSpec) -> tuple:
    """The filter's arguments after (c, q) for the white fix error the likelihood fits (no slow part)."""
    return np.zeros(table.B), np.full(table.B, math.inf), spec.order, spec.prior


def _robust_scale(table: FixTable, w, c, q, how, spec: NoiseSpec) -> tuple[np.ndarray, np.ndarray]:
    """(c, q) of the tracks with their own estimate (``how`` ESTIMATED) scaled down by the track's
    median NIS over 2 ln 2 (never up).

    At a fixed ratio q/c the innovation covariance is proportional to c, so the NIS of every fix
    scales as 1/c: the median NIS gives the scale that gross outliers cannot inflate, where the
    mean (the Gaussian estimate) is pulled up by them and the gate opens wide enough to keep
    them.  Estimates that are given (--sigma, --q) are not scaled."""
    if spec.sigma_m is not None or spec.q is not None:
        return c, q
    nis = np.empty(table.N)
    flag = np.empty(table.N, dtype=np.int8)
    X = np.empty((1, 2, spec.order + 1))
    P = np.empty((1, spec.order + 1, spec.order + 1))
    filter_tracks(table.offsets, table.t, table.east, table.north, w, c, q, *_white(table, spec), math.inf,
                  spec.max_rej, spec.max_gap_s, False, False, X, P, nis, flag, np.zeros((table.B, 6)))
    ok = np.isfinite(nis)
    med = median_by(np.repeat(np.arange(table.B), table.counts), nis, np.arange(table.B), ok)
    factor = np.where(np.isfinite(med) & (med > 0) & (how == ESTIMATED), np.minimum(1.0, med / _MEDIAN_NIS), 1.0)
    return c * factor, q * factor


def _gated_mask(table: FixTable, w, c, q, spec: NoiseSpec) -> np.ndarray:
    """The likelihood mask of the gated filter run with (c, q): its outliers and manoeuvres are left
    out, and a reset starts a new stretch."""
    flag = np.empty(table.N, dtype=np.int8)
    nis = np.empty(table.N)
    stats = np.zeros((table.B, 6))
    X = np.empty((1, 2, spec.order + 1))
    P = np.empty((1, spec.order + 1, spec.order + 1))
    filter_tracks(table.offsets, table.t, table.east, table.north, w, c, q, *_white(table, spec), spec.gate,
                  spec.max_rej, spec.max_gap_s, False, False, X, P, nis, flag, stats)
    return np.where((flag == OUTLIER) | (flag == MANOEUVRE), SKIP,
                    np.where((flag == RESET) | (flag == INIT), RESTART, USE)).astype(np.int8)


