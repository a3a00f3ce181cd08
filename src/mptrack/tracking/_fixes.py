"""Tracking one position-fix track: the readable per-track reference of the tracking engine.

:func:`track_fixes` filters one track with given noise parameters through the
library's general filters (:func:`._gated.track_gated` on the continuous
model, 4 x 4 state, Van Loan discretisation per interval; or a registered
linear filter on a regular grid) and builds the same point table as the
engine.  The engine (:mod:`._run`) is tested against it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._core.data_checks import check_frame
from .._core.finiteness import renamed
from .._core.validation import LATITUDE, LONGITUDE, as_real, as_vector, check_positive, lookup
from ..cellular import MOTIONS
from ..radio import PATH_LOSS_MODELS
from ..errors import ParameterError
from ..linear import get_filter
from ..result import FilterResult
from ._columns import FixTable
from ..models import ContinuousLinearModel
from ._track_filter import MANOEUVRE_FACTOR
from ._fix_error import SLOW_TAU_S, slow_error_variance
from ._gated import first_fix_prior, measured_states, nis_threshold, rts_smoother_gated, track_gated
from ._noise import SCOPES
from ._output import point_table
from ._registry import DEFAULT_SIGMA_M, get_cell_method, get_fix_filter, get_model

__all__ = ["TrackOptions", "FIX_ONLY", "CELL_ONLY", "track_fixes", "fix_variances", "fix_error_model",
           "grid_filter_track"]

#: The settings of :class:`TrackOptions` that apply to position fixes only, and to cellular measurements
#: only (a cell table given): the one list the command line and :func:`mptrack.track` refuse by.
FIX_ONLY = ("model", "filter", "smooth", "q", "sigma_m", "noise", "gate_probability", "max_gap_s")
CELL_ONLY = ("method", "motion", "path_loss", "q_km2", "r_km2", "scan_interval_s")


# Cellular process noise defaults.  The random walk's is Bouzera et al. (2017)'s Q0 (km^2 per scan).
# A CV model needs a spectral density of a vehicle's or walker's manoeuvres: on simulated urban
# drives (4 seeds x 6 tracks x 300 s, 3 cells) 1 m^2/s^3 beat the random walk on 21 of 24 tracks
# (0.1 and 10 m^2/s^3 did worse); the random walk's number read as km^2/s^3 doubled the error.
CELL_Q_KM2_RANDOM_WALK = 0.02
#: The largest fix noise (m) the engine's arithmetic handles (TrackOptions.__post_init__).
SIGMA_M_MAX = 1e70
CELL_Q_KM2_CV = 1e-6
#: A gap longer than this (s) starts a new segment of a track (TrackOptions.max_gap_s): ten minutes without
#: a fix leave the motion before them no use for the motion after them.
MAX_GAP_S = 600.0


@dataclass(frozen=True)
class TrackOptions:
    """Settings of ``mptrack track`` (units in the names).

    model             motion model name (MODELS): "cv" or "ca"
    filter            position-fix filter (FIX_FILTERS): "kf" (gated, irregular times) or a linear filter name
    q                 process-noise spectral density (m^2/s^3 for cv, m^2/s^5 for ca); None: estimated
    sigma_m           1-sigma fix noise per axis (m) where a fix has no accuracy_m; None: estimated
                      (with accuracy_m, a scale factor on it is estimated instead)
    noise             "track": noise estimated per track (short tracks share one estimate);
                      "file": one estimate for the whole input
    gate_probability  chi-square probability of the NIS gate (None: no gating); 0.999 -> 13.82 for 2-D fixes
    smooth            add an RTS smoothing pass (fixed interval, whole track)
    gap_s             an interval longer than this flags the point after it as following a gap (s)
    max_gap_s         a gap longer than this starts a new segment: the fix after it initialises the filter
                      again (s; None: never)
    method            cellular method (CELL_METHODS): "locate" (each scan placed as a geolocation request),
                      or a range filter over time, "ekf", "fekf" or "fcs"
    motion            cellular motion model: "random-walk" (the paper's) or "cv"
    path_loss         path-loss model for RSS -> range (mptrack.radio.PATH_LOSS_MODELS)
    q_km2             cellular process noise: random walk, km^2 per scan; cv, km^2/s^3; None: the
                      paper's 0.02 km^2 per scan for the random walk, 1e-6 km^2/s^3 (1 m^2/s^3) for cv
    r_km2             cellular range-noise variance (km^2; the paper's R0 = 0.222)
    scan_interval_s   cellular scan grid step (None: median interval between scans)
    """

    model: str = "cv"
    filter: str = "kf"
    q: float | None = None
    sigma_m: float | None = None
    noise: str = "track"
    gate_probability: float | None = 0.999
    smooth: bool = False
    gap_s: float = 30.0
    max_gap_s: float | None = MAX_GAP_S
    method: str = "locate"
    motion: str = "random-walk"
    path_loss: str = "cost231-wi-nlos"
    q_km2: float | None = None
    r_km2: float = 0.222
    scan_interval_s: float | None = None

    def __post_init__(self) -> None:
        with renamed(name="model"):
            get_model(self.model)
        with renamed(name="filter"):
            object.__setattr__(self, "filter", get_fix_filter(self.filter))
        if self.max_gap_s == float("inf"):   # inf bridges every gap, as None does
            object.__setattr__(self, "max_gap_s", None)
        with renamed(name="method"):
            get_cell_method(self.method)
        lookup("motion", self.motion, dict.fromkeys(MOTIONS), what="cellular motion model", fold=str)
        lookup("path_loss", self.path_loss, PATH_LOSS_MODELS, what="path-loss model", fold=str)
        if self.noise not in SCOPES:
            raise ParameterError(f"noise: expected one of {', '.join(SCOPES)}, got {self.noise!r}")
        for name, allow_zero in (("q", True), ("sigma_m", False), ("gap_s", False), ("max_gap_s", False),
                                 ("q_km2", True), ("r_km2", False)):
            if getattr(self, name) is not None:
                check_positive(name, getattr(self, name), allow_zero=allow_zero)
        # the filters square sigma_m and integrate q over dt^3: keep both where that stays a normal float;
        # the gated KF also multiplies two variances (the 2x2 innovation covariance's determinant,
        # sigma_m^4): it overflowed from sigma_m = 1e80 (NaN positions), 1e75 still ran; 1e70 leaves
        # a factor 1e28 in sigma_m^4 for the data's own scale
        if self.sigma_m is not None:
            as_real("sigma_m", self.sigma_m, low=1e-150, high=SIGMA_M_MAX, unit="m")
        if self.q is not None:
            as_real("q", self.q, low=0.0, high=1e150)
        if self.scan_interval_s is not None:
            check_positive("scan_interval_s", self.scan_interval_s)
        if self.gate_probability is not None:
            with renamed(probability="gate_probability"):
                nis_threshold(self.gate_probability, 2)

    @property
    def cell_q_km2(self) -> float:
        """The cellular process noise in use (the default of ``motion`` where ``q_km2`` is None)."""
        if self.q_km2 is not None:
            return self.q_km2
        return CELL_Q_KM2_CV if self.motion == "cv" else CELL_Q_KM2_RANDOM_WALK

    @property
    def gate(self) -> float:
        """The NIS threshold of a 2-D fix (inf without gating)."""
        return np.inf if self.gate_probability is None else nis_threshold(self.gate_probability, 2)


def fix_variances(rows: pd.DataFrame, options: TrackOptions) -> np.ndarray:
    """Variance (m^2 per axis) of each fix of one track when the noise is not estimated: accuracy_m^2
    where given, else sigma_m^2 (or DEFAULT_SIGMA_M)."""
    sigma = DEFAULT_SIGMA_M if options.sigma_m is None else options.sigma_m
    if "accuracy_m" not in rows.columns:
        return np.full(len(rows), sigma ** 2)
    acc = rows["accuracy_m"].to_numpy(float)
    return np.where(np.isfinite(acc) & (acc > 0), acc ** 2, sigma ** 2)


def check_fix_rows(name: str, rows) -> pd.DataFrame:
    """Rows of one track of position fixes as :func:`mptrack.io.iter_tracks` gives them: columns time, t
    (strictly increasing seconds), row, lat/lon or x/y, optional accuracy_m (NaN: not given)."""
    coords = ("lat", "lon") if isinstance(rows, pd.DataFrame) and "lat" in rows.columns else ("x", "y")
    check_frame(name, rows, ("time", "t", "row") + coords,
                {"t": {}, "lat": LATITUDE, "lon": LONGITUDE, "x": {}, "y": {},
                 "accuracy_m": dict(allow_nan=True, low=0.0)})
    if np.any(np.diff(rows["t"].to_numpy(dtype=float)) <= 0):
        raise ParameterError(f"{name}.t: expected strictly increasing times (one track in time order)")
    return rows


def _enu(rows: pd.DataFrame) -> tuple[FixTable, np.ndarray]:
    table = FixTable.from_frame(rows.assign(track_id="_"))
    return table, np.column_stack([table.east, table.north])


def track_fixes(track_id: str, rows: pd.DataFrame, options: TrackOptions = TrackOptions(), *,
                fix_var=None, q: float | None = None, slow_var: float | None = None,
                slow_tau_s: float = SLOW_TAU_S) -> pd.DataFrame:
    """Filter (and optionally smooth) one track of validated position fixes: the per-track reference the
    columnar engine is tested against.

    Positions are east/north metres in the track's local frame (origin at the first fix); no noise is
    estimated here.

    Parameters
    ----------
    track_id : str
    rows : pandas.DataFrame
        A track from :func:`mptrack.io.iter_tracks` (columns t, time, row, lat/lon or x/y, accuracy_m).
    options : TrackOptions, optional
        The settings of ``mptrack track``.
    fix_var : array_like, shape (T,), optional
        Fix variances (m^2) (default :func:`fix_variances`).
    q : float, optional
        Process-noise density (default ``options.q`` or the model's).
    slow_var : float, optional
        Stationary variance (m^2 per axis) of the fix error's slow part (default: what the total error
        leaves, :func:`._fix_error.slow_error_variance`; the gated KF only).
    slow_tau_s : float, optional
        Time constant (s) of the slow part.

    Returns
    -------
    pandas.DataFrame
        The track's point table.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, Estimation with Applications to Tracking and Navigation,
           Wiley, 2001. doi:10.1002/0471221279
    .. [2] A. Gelb (ed.), Applied Optimal Estimation, MIT Press, 1974.
    """
    check_fix_rows("rows", rows)
    if not isinstance(options, TrackOptions):
        raise ParameterError(f"options: expected TrackOptions, got {type(options).__name__}")
    spec = get_model(options.model)
    table, z = _enu(rows)
    t = table.t
    r = fix_variances(rows, options) if fix_var is None else as_vector("fix_var", fix_var, len(rows), low=0.0)
    q = (spec.default_q if options.q is None else options.q) if q is None else check_positive("q", q, allow_zero=True)
    if slow_var is None:
        has_acc = "accuracy_m" in rows.columns and bool(np.any(np.isfinite(rows["accuracy_m"].to_numpy(float))))
        median = float(np.median(r))
        slow_var = float(slow_error_variance(np.ones(1), np.array([median]), np.array([has_acc]))[0])
    slow_var = check_positive("slow_var", slow_var, allow_zero=True)
    model, levels, info, prior = fix_error_model(spec, q, slow_var, check_positive("slow_tau_s", slow_tau_s))
    pos = measured_states(model.H)
    extra = {"meas_east_m": z[:, 0], "meas_north_m": z[:, 1], "fix_sigma_m": np.sqrt(r)}
    if table.geographic:
        extra["meas_lat"], extra["meas_lon"] = table.lat, table.lon
    # the filters' arrays are the columns of rows and the model is built from q: their errors name those
    # (times 1e300 s apart, q = 1e308 overflow the discretisation)
    with renamed(times="rows", z="rows", R="rows", gated="rows", model="q"):
        if options.filter == "kf":
            gated = track_gated(model, t, z, r[:, None, None] * np.eye(2), prior,
                                gate_probability=options.gate_probability, manoeuvre_noise=levels,
                                prior_information=info, max_gap_s=options.max_gap_s)
            res = rts_smoother_gated(gated) if options.smooth else gated
            flags, nis, times, t_out = gated.flag, gated.nis, table.time, t
            method = "KF-gated" + ("+RTS" if options.smooth else "")
        else:
            res, flags, nis, t_out, extra = grid_filter_track(spec, q, options, t, z, r)
            pos = measured_states(spec.build(q, 1.0).H)
            times = _time_like(t_out, table.time)
            method = options.filter.upper() + ("+RTS" if options.smooth else "")
    vel = res.x[:, [p + 1 for p in pos]]
    P = res.P
    dof = np.where(np.isnan(nis), 0, 2)
    offsets = np.array([0, len(t_out)])
    return point_table([track_id], offsets, times, t_out, res.x[:, pos[0]], res.x[:, pos[1]], vel,
                       P[:, pos[0], pos[0]], P[:, pos[0], pos[1]], P[:, pos[1], pos[1]], nis, dof, flags,
                       options.gap_s, table.origin if table.geographic else None, method, extra).to_pandas()


def fix_error_model(spec, q: float, slow_var: float, tau_s: float):
    """The continuous model of ``spec`` (density q) with the fix error's slow part (:mod:`._fix_error`) as one
    more state per axis after the chain's -- per axis [position, velocity, (acceleration,) b], b a
    first-order Gauss-Markov process of stationary variance ``slow_var`` and time constant ``tau_s`` (inf: a
    constant), measured with the position (H = [1, 0, ..., 1]); without a slow part (slow_var 0) the
    model of ``spec`` itself.  Returns (model, the two manoeuvre hypotheses' spectral densities (the
    motion's scaled, b's not), the information a restart starts from (b's prior), the first fix's prior
    variances)."""
    base = spec.build(q, 1.0)
    f = MANOEUVRE_FACTOR
    if slow_var == 0.0:
        return base, None, None, np.tile(spec.prior_variances, 2)
    r = spec.order
    chain = np.eye(r, k=1)
    Phi1 = np.zeros((r + 1, r + 1))
    Phi1[:r, :r] = chain
    Phi1[r, r] = -1.0 / tau_s
    L1 = np.zeros((r + 1, 2))
    L1[r - 1, 0] = 1.0
    L1[r, 1] = 1.0
    H1 = np.zeros((1, r + 1))
    H1[0, 0] = H1[0, r] = 1.0
    two = lambda a: np.kron(np.eye(2), a)  # noqa: E731 - both axes, block-diagonal
    qb = 2.0 * slow_var / tau_s
    model = ContinuousLinearModel(two(Phi1), two(L1), two(np.diag([q, qb])), two(H1), np.eye(2),
                                  name=f"{spec.name} with a slow fix error")
    with np.errstate(over="ignore"):   # beyond the float range: the filter's discretisation check names q
        levels = tuple(two(np.diag([m * q, qb])) for m in (f, f * f))
    info = two(np.diag(np.r_[np.zeros(r), 1.0 / slow_var]))
    prior = np.tile(np.r_[spec.prior_variances, slow_var], 2)
    return model, levels, info, prior


def _time_like(t_grid: np.ndarray, times: np.ndarray) -> np.ndarray:
    if np.issubdtype(times.dtype, np.datetime64):
        return np.rint(t_grid * 1e9).astype("int64").astype("datetime64[ns]")
    return t_grid


def grid_filter_track(spec, q: float, options: TrackOptions, t, z, r):
    """A registered linear filter with motion model ``spec`` (density q) on the track resampled to a
    regular grid at the median interval (a grid slot keeps its first fix; empty slots predict only;
    no gating; R = the median fix variance): (result, flags, NIS, grid times, extra columns)."""
    from ..linear import rts_smoother

    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    bins = np.rint((t - t[0]) / dt).astype(np.int64)
    t_grid = t[0] + dt * np.arange(bins[-1] + 1)
    zg = np.full((len(t_grid), 2), np.nan)
    first = np.r_[True, bins[1:] != bins[:-1]]
    zg[bins[first]] = z[first]
    disc = spec.build(q, float(np.median(r))).discretize(dt)
    x0, P0 = first_fix_prior(disc.H, z[0], r[0] * np.eye(2), np.tile(spec.prior_variances, 2))
    # the prior is at the first fix: start one step before it
    x_start = np.linalg.solve(disc.F, x0)
    # the result carries the NIS of each grid measurement against the one-step prediction
    res: FilterResult = get_filter(options.filter).run(disc, zg, x_start, P0)
    nis = res.nis
    flags = np.where(np.isnan(nis), 2, 0).astype(np.int8)
    extra = {"meas_east_m": zg[:, 0], "meas_north_m": zg[:, 1]}
    if options.smooth:
        res = rts_smoother(disc, res)
    return res, flags, nis, t_grid, extra
