"""Linear filters: Kalman (KF), Lainiotis (LF), their join (JKLF), steady-state (SSKF,
SSLF, JSSKLF), FIR steady-state, and per-axis running of model B.  They return
:class:`mptrack.result.FilterResult` (exported from :mod:`mptrack.result`, its one home; the name
still imports from here for one release, with a DeprecationWarning)."""

from .._core.moved import moved_names
from ._joint import join_results, per_axis
from ._kalman import kalman_filter, kalman_step
from ._lainiotis import lainiotis_filter, lainiotis_step
from ._registry import (
    FILTERS,
    IMPLEMENTATIONS,
    FilterSpec,
    Implementation,
    get_filter,
    get_implementation,
)
from ._steady import fir_coefficients, fir_filter, fir_order, steady_state_filter

__all__ = [
    "kalman_filter",
    "kalman_step",
    "lainiotis_filter",
    "lainiotis_step",
    "steady_state_filter",
    "fir_filter",
    "fir_order",
    "fir_coefficients",
    "join_results",
    "per_axis",
    "FILTERS",
    "FilterSpec",
    "get_filter",
    "IMPLEMENTATIONS",
    "Implementation",
    "get_implementation",
]
from ._irregular import (
    kalman_filter_irregular,
    rts_smoother_irregular,
    sampling_intervals,
)
from ._prediction import (
    predict_ahead,
    prediction_covariance,
    prediction_matrices,
    steady_state_predictor,
)
from ._smoother import rts_smoother, steady_state_smoother
from ._fit import FitResult, fit_em, fit_ml

__all__ += [
    "steady_state_predictor",
    "prediction_matrices",
    "prediction_covariance",
    "predict_ahead",
    "rts_smoother",
    "steady_state_smoother",
    "kalman_filter_irregular",
    "rts_smoother_irregular",
    "sampling_intervals",
    "fit_em",
    "fit_ml",
    "FitResult",
]

#: names whose one home is elsewhere (issue 34)
__getattr__ = moved_names(__name__, {"FilterResult": "mptrack.result"})
