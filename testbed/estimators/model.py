"""The nonlinear design model a plug-in may use: ``f``, ``F``, ``h``, ``H`` in the loop's input.

:func:`nonlinear_model` gives a plug-in what the built-in ``ekf`` and ``ukf`` run on (the
rig's MJCF at nominal parameters over one control period, composed with a matched design's
extra states; :mod:`testbed.estimators.nonlinear`) in the coordinates the plug-in receives:

- ``u`` is the input the loop hands the estimator's ``step(y, u)`` (the design model's
  coordinates: the applied input minus the rig's operating input at the estimate, for the
  helicopter the voltage that compensates gravity);
- ``x_hat`` is the estimate the loop's ``u`` is relative to: the estimator's own ``x``
  before the step. It is a required argument of every function, so the operating input is
  always added back (:meth:`NonlinearModel.applied_input`): the MuJoCo transition gets the
  volts the motors got.

The filter built from these functions by the textbook equations is the built-in one (the
tests compare a filterpy EKF written from ``docs/extending.md`` with ``ekf``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from testbed.design import DesignModel


class NonlinearModel:
    """``x_{k+1} = f(x_k, u_k) + w_k``, ``y_k = h(x_k, u_k) + v_k`` of a design, with
    ``w ~ N(0, Q)``, ``v ~ N(0, R)``.

    Shapes: ``x`` is one state (n,) or rows (M, n); ``u`` (k,) or (M, k) and ``x_hat`` (n,)
    or (M, n) broadcast to ``x``'s rows (a UKF's sigma points of one estimate share its
    ``u`` and ``x_hat``). One state in, one result out ((n,), (n, n), (m,), (m, n)); rows
    in, rows out ((M, n), (M, n, n), (M, m), (M, m, n)). Every function is row-independent
    and deterministic; all the rows of one call go through one batched MuJoCo rollout.

    Units: the design's (``state_names``/``state_units`` of the design: radians, rad/s,
    volts...); ``dt_s`` seconds.

    Parameters
    ----------
    design : DesignModel
        The design the factory received (paper or matched/augmented).
    eps : float
        Finite-difference step of ``F`` (state units).
    centered : bool
        Central instead of forward differences for ``F``.
    nthread : int
        Rollout threads (0: the calling thread; the results do not depend on it).
    jacobian, jacobian_points
        The method of ``F``, as the built-in ``ekf``'s
        (:class:`testbed.estimators.mujoco_model.MujocoProcessModel`).

    Attributes
    ----------
    n, m, k : int
        State, measurement (``design.measurement_index``) and input dimensions.
    dt_s : float
        Control period, s.
    Q, R : ndarray, shapes (n, n), (m, m)
        ``design.discrete.Q`` and ``design.discrete.R``.
    x0, P0 : ndarray, shapes (n,), (n, n)
        The design's prior.
    state_names, input_names, measurement_names : tuple of str
    """

    def __init__(self, design: DesignModel, *, eps: float | None = None,
                 centered: bool = False, nthread: int = 0, jacobian: str = "step",
                 jacobian_points: int = 1) -> None:
        from testbed.estimators.nonlinear import FD_EPS, nonlinear_models

        rig, process, measure = nonlinear_models(design, eps=FD_EPS if eps is None else eps,
                                                 centered=centered, nthread=nthread,
                                                 jacobian=jacobian,
                                                 jacobian_points=jacobian_points)
        self._process, self._measure = process, measure
        self._rig, self._params, self._nr = rig, rig.params, rig.n_states
        self._offsets = design.input_transform is not None
        self.n, self.k = int(design.n), len(design.input_names)
        self.m = len(design.measurement_index)
        self.dt_s = float(design.dt_s)
        self.Q = np.array(design.discrete.Q, float)
        self.R = np.array(design.discrete.R, float)
        self.x0 = np.array(design.x0, float)
        self.P0 = np.array(design.P0, float)
        self.state_names = tuple(design.state_names)
        self.input_names = tuple(design.input_names)
        self.measurement_names = tuple(design.measurement_names[i]
                                       for i in design.measurement_index)

    def _rows(self, x: npt.ArrayLike, u: npt.ArrayLike,
              x_hat: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, bool]:
        """``x`` as rows (M, n), the applied input (M, k), and whether ``x`` was one state."""
        X = np.asarray(x, dtype=float)
        single = X.ndim == 1
        X = X[None] if single else X
        if X.ndim != 2 or X.shape[1] != self.n:
            raise ValueError(f"x must have shape ({self.n},) or (M, {self.n}), got "
                             f"{np.shape(x)}")
        return X, self.applied_input(u, x_hat, rows=len(X)), single

    def applied_input(self, u: npt.ArrayLike, x_hat: npt.ArrayLike,
                      rows: int | None = None) -> np.ndarray:
        """The input the rig got: ``u + [operating_input(x_hat), 0]``, shape (M, k).

        Parameters
        ----------
        u : array_like, shape (k,) or (M, k)
            The loop's input (design coordinates).
        x_hat : array_like, shape (n,) or (M, n)
            The estimate ``u`` is relative to (the estimator's ``x`` before the step).
        rows : int, optional
            Broadcast to this many rows (default: the rows of ``u`` and ``x_hat``).
        """
        U = np.atleast_2d(np.asarray(u, dtype=float))
        XH = np.atleast_2d(np.asarray(x_hat, dtype=float))
        if U.shape[-1] != self.k or U.ndim != 2:
            raise ValueError(f"u must have shape ({self.k},) or (M, {self.k}), got "
                             f"{np.shape(u)}")
        if XH.shape[-1] != self.n or XH.ndim != 2:
            raise ValueError(f"x_hat must have shape ({self.n},) or (M, {self.n}), got "
                             f"{np.shape(x_hat)}")
        M = max(len(U), len(XH)) if rows is None else int(rows)
        try:
            U = np.broadcast_to(U, (M, self.k))
            XH = np.broadcast_to(XH, (M, self.n))
        except ValueError:
            raise ValueError(f"u {np.shape(u)} and x_hat {np.shape(x_hat)} do not broadcast "
                             f"to {M} rows") from None
        if not self._offsets:
            return np.array(U)
        extra = np.asarray(self._rig.operating_input(self._params, XH[:, :self._nr]), float)
        if extra.shape[1] < self.k:
            extra = np.pad(extra, ((0, 0), (0, self.k - extra.shape[1])))
        return U + extra

    def f(self, x: npt.ArrayLike, u: npt.ArrayLike, x_hat: npt.ArrayLike) -> np.ndarray:
        """The state one control period later, (n,) or (M, n)."""
        X, ua, single = self._rows(x, u, x_hat)
        out = np.asarray(self._process(X, ua), float)
        return out[0] if single else out

    def F(self, x: npt.ArrayLike, u: npt.ArrayLike, x_hat: npt.ArrayLike) -> np.ndarray:
        """``df/dx`` at the applied input, (n, n) or (M, n, n): the built-in ``ekf``'s
        Jacobian (``jacobian``: one physics step's derivatives held over the period by
        default, ``"rollout"`` finite differences of the whole period)."""
        X, ua, single = self._rows(x, u, x_hat)
        out = np.asarray(self._process.jacobian(X, ua), float)
        return out[0] if single else out

    def h(self, x: npt.ArrayLike, u: npt.ArrayLike, x_hat: npt.ArrayLike) -> np.ndarray:
        """The channels ``design.measurement_index`` at state ``x``, (m,) or (M, m)."""
        X, ua, single = self._rows(x, u, x_hat)
        out = np.asarray(self._measure(X, ua), float)
        return out[0] if single else out

    def H(self, x: npt.ArrayLike, u: npt.ArrayLike, x_hat: npt.ArrayLike) -> np.ndarray:
        """``dh/dx``, (m, n) or (M, m, n)."""
        X, ua, single = self._rows(x, u, x_hat)
        out = np.asarray(self._measure.jacobian(X, ua), float)
        return out[0] if single else out

    def __repr__(self) -> str:
        return (f"NonlinearModel(n={self.n}, m={self.m}, k={self.k}, dt_s={self.dt_s:g}, "
                f"states={list(self.state_names)})")


def nonlinear_model(design: DesignModel, **options: Any) -> NonlinearModel:
    """The nonlinear model of ``design`` for a plug-in (:class:`NonlinearModel`; options:
    ``eps``, ``centered``, ``nthread``, ``jacobian``, ``jacobian_points``).

    Raises
    ------
    ValueError
        The design names no MuJoCo rig (``design.extras["rig_type"]``), or its states are
        not the rig's joint state (first, in an augmented design).
    """
    return NonlinearModel(design, **options)
