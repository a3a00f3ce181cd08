"""The tracking models of Assimakis & Adam 2014 (2-D) and 2015 (3-D)."""

from __future__ import annotations

from typing import Literal

from .._core.finiteness import derived_from
from .._core.validation import check_int, check_positive
from ..errors import ParameterError
from ._linear import LinearGaussianModel, stack_axes

__all__ = ["assimakis_model_a", "assimakis_model_b", "MeasurementForm"]

MeasurementForm = Literal["printed", "position"]


def assimakis_model_b(dt: float = 1.0, sigma_q2: float = 0.01, sigma_r2: float = 0.1,
                      measurement: MeasurementForm = "printed") -> LinearGaussianModel:
    """Model B of Assimakis & Adam: one axis, state [position, velocity], n = 2, m = 1.

    F = [[1, dt], [0, 1]], G = [dt/2, 1]^T, Q = sigma_q2 G G^T, R = sigma_r2 (Assimakis & Adam 2014,
    eq. 3).

    Parameters
    ----------
    dt : float, optional
        Sampling interval (s).
    sigma_q2 : float, optional
        Acceleration-noise variance, in the squared units of the state.
    sigma_r2 : float, optional
        Measurement-noise variance, in the squared units of the state.
    measurement : {"printed", "position"}, optional
        ``"printed"`` uses H = [1, dt] as printed in the papers (their published FIR order M = 17 depends
        on it); ``"position"`` the textbook H = [1, 0] (docs/errata.md).

    Returns
    -------
    LinearGaussianModel

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).

    Examples
    --------
    >>> from mptrack.models import assimakis_model_b
    >>> assimakis_model_b().H
    array([[1., 1.]])
    """
    dt = check_positive("dt", dt)
    sigma_q2 = check_positive("sigma_q2", sigma_q2, allow_zero=True)
    sigma_r2 = check_positive("sigma_r2", sigma_r2)
    if measurement == "printed":
        H = [[1.0, dt]]
    elif measurement == "position":
        H = [[1.0, 0.0]]
    else:
        raise ParameterError(f"measurement: expected 'printed' or 'position', got {measurement!r}")
    F = [[1.0, dt], [0.0, 1.0]]
    G = [[0.5 * dt], [1.0]]
    with derived_from(dt=dt, sigma_q2=sigma_q2, sigma_r2=sigma_r2):
        return LinearGaussianModel.from_noise_gain(F, H, G, [[sigma_q2]], [[sigma_r2]], dt=dt,
                                                   name=f"model B (H {measurement})")


def assimakis_model_a(axes: int = 2, dt: float = 1.0, sigma_q2: float = 0.01, sigma_r2: float = 0.1,
                      measurement: MeasurementForm = "printed") -> LinearGaussianModel:
    """Model A of Assimakis & Adam: all axes jointly, n = 2 axes, m = axes.

    The state is [s_x, v_x, s_y, v_y(, s_z, v_z)]; F, G, H, Q, R are the block-diagonal stack of model B
    (Assimakis & Adam 2014, eq. 2; Assimakis & Adam 2015 for three axes).

    Parameters
    ----------
    axes : int, optional
        2 (the 2014 paper) or 3 (the 2015 paper).
    dt : float, optional
        Sampling interval (s).
    sigma_q2 : float, optional
        Acceleration-noise variance of each axis.
    sigma_r2 : float, optional
        Measurement-noise variance of each axis.
    measurement : {"printed", "position"}, optional
        ``"printed"`` uses H = [1, dt] as printed in the papers (their published FIR order M = 17 depends
        on it); ``"position"`` the textbook H = [1, 0] (docs/errata.md).

    Returns
    -------
    LinearGaussianModel

    References
    ----------
    .. [1] N. Assimakis and M. Adam, "Global systems for mobile position tracking using Kalman and Lainiotis
           filters", The Scientific World Journal, vol. 2014, Article ID 130512, 8 pp., 2014.
           doi:10.1155/2014/130512
    .. [2] N. Assimakis and M. Adam, "Mobile position tracking in three dimensions using Kalman and Lainiotis
           filters", The Open Mathematics Journal, vol. 8, pp. 1–6, 2015 (Bentham Open).

    Examples
    --------
    >>> from mptrack.models import assimakis_model_a
    >>> model = assimakis_model_a(axes=3)
    >>> model.n, model.m
    (6, 3)
    """
    axes = check_int("axes", axes, minimum=1)
    if axes not in (2, 3):
        raise ParameterError(f"axes: the papers' model A has 2 or 3 axes, got {axes}")
    return stack_axes(assimakis_model_b(dt, sigma_q2, sigma_r2, measurement), axes,
                      name=f"model A {axes}-D (H {measurement})")
