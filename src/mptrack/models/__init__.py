"""Linear-Gaussian state-space models and the papers' model constructors."""

from ._linear import LinearGaussianModel, require_model, stack_axes
from ._paper import assimakis_model_a, assimakis_model_b

__all__ = ["LinearGaussianModel", "require_model", "stack_axes", "assimakis_model_a", "assimakis_model_b"]
