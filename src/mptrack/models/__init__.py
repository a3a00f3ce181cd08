"""Linear-Gaussian state-space models: the validated model record, the papers' models,
and continuous-time motion models discretised exactly."""

from ._continuous import (
    ContinuousLinearModel,
    ca_discrete_white_noise,
    constant_acceleration,
    constant_acceleration_continuous,
    constant_velocity,
    constant_velocity_continuous,
    cv_discrete_white_noise,
    discretize,
    discretize_intervals,
    van_loan,
)
from ._linear import LinearGaussianModel, require_model, stack_axes
from ._nonlinear import (
    MeasurementModel,
    NonlinearModel,
    bearings,
    nonlinear_model,
    position,
    range_bearing,
    range_rate,
    ranges,
    stack_measurements,
    tdoa,
    wrap_angles,
)
from ._paper import assimakis_model_a, assimakis_model_b

__all__ = [
    "LinearGaussianModel",
    "require_model",
    "stack_axes",
    "assimakis_model_a",
    "assimakis_model_b",
    "ContinuousLinearModel",
    "van_loan",
    "discretize",
    "discretize_intervals",
    "constant_velocity_continuous",
    "constant_acceleration_continuous",
    "constant_velocity",
    "constant_acceleration",
    "cv_discrete_white_noise",
    "ca_discrete_white_noise",
    "NonlinearModel",
    "MeasurementModel",
    "nonlinear_model",
    "wrap_angles",
    "ranges",
    "bearings",
    "range_bearing",
    "range_rate",
    "tdoa",
    "position",
    "stack_measurements",
]
