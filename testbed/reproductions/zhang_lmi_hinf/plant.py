"""Zhang, Deng & Zhang (2018), Example 5.1: the nonlinear discrete stochastic system (49) and its
filter (50) (see docs/references.md).

System (49), state ``x = [x1, x2]``, scalar disturbance ``v_k``, scalar white noise ``w_k``
(``E w = 0``, ``E w^2 = 1``; drawn standard normal here)::

    x1+ = 0.6 x1^3 / (1 + x1^2 + x2^2) + 0.1 v x1 + 0.5 x2 sin(v) w
    x2+ = 0.65 x2 + 0.1 x2 x1 + 0.5 v sin(x2) w
    y1  = 0.5 x1 + v sin(x1),   y2 = 0.5 x2 + v sin(x2)
    z   = 0.1 x1 + 0.1 x2

with ``v_k = 2 * 0.9999^k``. Filter (50): ``xhat+ = 0.5 xhat + 0.5 y``,
``zhat = 0.1 (xhat1 + xhat2)``, ``xhat_0 = 0`` (the paper's (23)). All quantities are
dimensionless; one step is one time unit.

Corollary 3 (the sufficient conditions (35)-(36)) for the affine form (28)
``x+ = f1 + h1 v + (f2 + h2 v) w``, ``y = g1 + g2 v``, ``z = m`` with the filter (29)
``xhat+ = fhat(xhat) + ghat(xhat) y``, ``zhat = mhat(xhat)`` and ``V = x'Q1 x + xhat'Q2 xhat``::

    (35)  2 [h1'Q1 h1 + h2'Q1 h2 + (ghat g2)'Q2 (ghat g2)] - gamma^2 I <= 0
    (36)  2 [f1'Q1 f1 + f2'Q1 f2 + (fhat + ghat g1)'Q2 (fhat + ghat g1)]
              - x'Q1 x - xhat'Q2 xhat + 2 |m(x)|^2 + 2 |mhat(xhat)|^2 <= 0

Corrections to the printed (35)-(36), derived from (31)-(33) with ``Q = diag(Q1, Q2)``:

- the printed conditions drop the noise terms ``h2'Q1 h2`` and ``f2'Q1 f2``, which (33) and
  (32) contain (``h~2 = [h2; 0]``, ``f~2 = [f2; 0]``);
- the printed (36) has ``+ xhat'Q2 xhat``; ``-eta'Q eta`` gives ``- xhat'Q2 xhat``.

(49) is not exactly affine in ``v``: the term ``0.5 x2 sin(v) w``. Since ``f2 = 0`` and
``|sin v| <= |v|``, ``E V`` of (49) is bounded by that of the affine system with
``h2 = [0.5 x2; 0.5 sin(x2)]``, so Corollary 3 with this ``h2`` is a valid sufficient
condition. For Example 5.1: ``f1 = [0.6 x1^3 / (1 + |x|^2); 0.65 x2 + 0.1 x1 x2]``,
``h1 = [0.1 x1; 0]``, ``f2 = 0``, ``g1 = 0.5 x``, ``g2 = [sin x1; sin x2]``,
``fhat = 0.5 xhat``, ``ghat = 0.5 I``, ``m = 0.1 (x1 + x2)``, ``mhat = 0.1 (xhat1 + xhat2)``.

Corollary 2 itself: the HJI (27) (:func:`hji_values`, :func:`hji_check`) and its condition
(26) (:func:`output_lower_bound_check`), which (27) does not imply. All functions take a leading
batch axis: states of shape ``(..., 2)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from filters import FiniteEscapeError, LMIHInfFilter
from filters._deprecated import deprecated_alias
from filters.lmi_hinf import StochasticLinearSystem

#: Filter (50): ``xhat+ = F xhat + G y``, ``zhat = C_Z xhat``.
FILTER_F = 0.5 * np.eye(2)
FILTER_G = 0.5 * np.eye(2)
#: Estimated output ``z = C_Z x`` (the filter uses the same combination of ``xhat``).
C_Z = np.array([[0.1, 0.1]])
STATE_NAMES = ("x1", "x2")
MEASUREMENT_NAMES = ("y1", "y2")
#: State magnitude beyond which the state has escaped (never reached from ``|x0| <~ 3``).
ESCAPE_BOUND = 1e6


def paper_disturbance(k: npt.ArrayLike) -> np.ndarray | float:
    """The paper's ``v_k = 2 * 0.9999^k`` (``k`` may be an array; dimensionless)."""
    k = np.asarray(k, dtype=float)
    out = 2.0 * 0.9999 ** k
    return float(out) if out.ndim == 0 else out


def _split(x: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    if x.ndim < 1 or x.shape[-1] != 2:
        raise ValueError(f"x must have shape (2,) or (..., 2), got shape {x.shape}")
    return x, x[..., 0], x[..., 1]


def drift(x: npt.ArrayLike) -> np.ndarray:
    """``f1(x)``: the noise- and disturbance-free part of (49), shape ``(..., 2)``."""
    x, x1, x2 = _split(x)
    return np.stack([0.6 * x1**3 / (1.0 + x1**2 + x2**2), 0.65 * x2 + 0.1 * x2 * x1], axis=-1)


def step(x: npt.ArrayLike, v: npt.ArrayLike, w: npt.ArrayLike) -> np.ndarray:
    """One step of (49): ``x_{k+1}`` from ``x_k``, ``v_k`` and ``w_k``.

    Parameters
    ----------
    x : array_like, shape (..., 2)
    v, w : array_like, shape broadcastable to ``x.shape[:-1]``

    Returns
    -------
    ndarray, shape (..., 2)
    """
    x, x1, x2 = _split(x)
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    f = drift(x)
    n1 = 0.1 * v * x1 + 0.5 * x2 * np.sin(v) * w
    n2 = 0.5 * v * np.sin(x2) * w
    return f + np.stack(np.broadcast_arrays(n1, n2), axis=-1)


def measure(x: npt.ArrayLike, v: npt.ArrayLike) -> np.ndarray:
    """``y_k = 0.5 x_k + v_k sin(x_k)`` (componentwise), shape ``(..., 2)``."""
    x, _, _ = _split(x)
    return 0.5 * x + np.asarray(v, dtype=float)[..., None] * np.sin(x)


def output(x: npt.ArrayLike) -> np.ndarray:
    """``z = 0.1 x1 + 0.1 x2``, shape ``(...)``."""
    x, x1, x2 = _split(x)
    return 0.1 * x1 + 0.1 * x2


def printed_filter(x0: npt.ArrayLike | None = None) -> LMIHInfFilter:
    """The filter (50) as the library's :class:`filters.LMIHInfFilter`: ``xhat+ = 0.5 xhat +
    0.5 y``, ``zhat = 0.1 (xhat1 + xhat2)``, ``xhat_0 = 0``; ``t_s`` counts steps."""
    return LMIHInfFilter.from_state_space(FILTER_F, FILTER_G,
                                          x0=np.zeros(2) if x0 is None else x0,
                                          C_z=C_Z, dt_s=1.0)


def filter_step(xhat: npt.ArrayLike, y: npt.ArrayLike) -> np.ndarray:
    """The map of filter (50), ``xhat_{k+1} = F xhat_k + G y_k`` with the matrices of
    :func:`printed_filter`, shape ``(..., 2)`` (for the pointwise HJI check on a grid)."""
    return np.asarray(xhat, dtype=float) @ FILTER_F.T + np.asarray(y, dtype=float) @ FILTER_G.T


class NonlinearDiscretePlant:
    """System (49) as a :class:`~testbed.experiment.numpy_plant.NumpyPlant` (``dt_s = 1``).

    Step ``k`` feels ``v_k = schedule(k) + u`` (``u`` of shape (..., 1), default 0) and the
    scalar noise ``w_k`` of each run; it delivers ``y_{k+1}`` with the schedule's
    ``v_{k+1}``. Beyond :data:`ESCAPE_BOUND` (or non-finite) it raises
    :class:`~filters.errors.FiniteEscapeError` (``quantity="state"``, ``time = k + 1``).

    Parameters
    ----------
    disturbance : {"paper", None}
        The paper's ``v_k = 2 * 0.9999^k`` or none.
    v : ndarray, shape (N,), optional
        The paper's ``v_0 .. v_{N-1}`` as computed for a Monte Carlo (vectorized ``pow``
        rounds differently from the scalar one in the last bit); later steps: the scalar.
    """

    dt_s = 1.0

    def __init__(self, disturbance: str | None = "paper", v: np.ndarray | None = None) -> None:
        if disturbance not in ("paper", None):
            raise ValueError(f"disturbance must be 'paper' or None, got {disturbance!r}")
        self.disturbance, self.v = disturbance, v

    def schedule(self, k: int) -> float:
        """Scheduled disturbance ``v_k`` (``2 * 0.9999^k`` or 0)."""
        if self.disturbance is None:
            return 0.0
        return float(self.v[k] if self.v is not None and k < len(self.v)
                     else paper_disturbance(k))

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]) -> np.ndarray:
        """``w_k ~ N(0, 1)``, shape ``batch``."""
        return np.zeros(batch) if rng is None else rng.standard_normal(batch)

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """``y_k = 0.5 x + v_k sin(x)``, shape (..., 2)."""
        return measure(x, np.full(np.shape(x)[:-1], self.schedule(k)))

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, dict[str, object]]:
        """``x_{k+1}``, ``y_{k+1}`` and the extras ``disturbance``, ``action_applied``
        (``[v_k]``), ``noise`` (``w_k``), ``z``."""
        v = self.schedule(k) + (0.0 if u is None else u[..., 0])
        with np.errstate(over="ignore", invalid="ignore"):
            x_next = step(x, v, noise)
        bad = ~np.all(np.abs(x_next) <= ESCAPE_BOUND, axis=-1)  # NaN counts
        if np.any(bad):
            raise FiniteEscapeError(f"the state escaped |x| <= {ESCAPE_BOUND:g}",
                                    time=float(k + 1), quantity="state",
                                    value=np.asarray(x_next)[bad][0].copy())
        v = np.atleast_1d(np.asarray(v, dtype=float))
        return x_next, self.observe(x_next, k + 1), {
            "disturbance": v, "action_applied": v, "noise": float(noise) if np.ndim(noise) == 0
            else noise, "z": output(x_next) if np.ndim(x_next) > 1 else float(output(x_next))}


class StochasticLinearPlant:
    """The system (44) of Example 5.2 driven by a known disturbance, as a
    :class:`~testbed.experiment.numpy_plant.NumpyPlant`.

    The system::

        x_{k+1} = A x + B v_k + (A_w x + B_w v_k) w_k,   y_k = C_y x_k + D_y v_k

    Parameters
    ----------
    system : filters.lmi_hinf.StochasticLinearSystem
    v : ndarray, shape (N,)
        ``v_0 .. v_{N-1}`` (the same value on every disturbance channel; 0 after).
    dt_s : float
    """

    def __init__(self, system: StochasticLinearSystem, v: np.ndarray, dt_s: float = 1.0):
        self.system, self.v, self.dt_s = system, np.asarray(v, dtype=float), dt_s
        self._ones = np.ones(system.n_v)

    def _v(self, k: int) -> np.ndarray:
        return (self.v[k] if k < len(self.v) else 0.0) * self._ones

    noise = NonlinearDiscretePlant.noise  # w_k ~ N(0, 1), shape batch

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """``y_k``, shape (..., n_y)."""
        return x @ self.system.C_y.T + self._v(k) @ self.system.D_y.T

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, dict[str, object]]:
        """``x_{k+1}`` and ``y_{k+1}`` (no extras)."""
        s, vk = self.system, self._v(k)
        x = x @ s.A.T + vk @ s.B.T + noise[..., None] * (x @ s.A_w.T + vk @ s.B_w.T)
        return x, self.observe(x, k + 1), {}


def cumulative_sums(z_err: np.ndarray, v: np.ndarray, gamma: float) -> dict[str, Any]:
    """The inequality (7) over a Monte Carlo: ``sum_i E|ztilde_i|^2`` against
    ``gamma^2 sum_i |v_i|^2`` at every ``k`` (Figures 3 and 7).

    Parameters
    ----------
    z_err : ndarray, shape (R, N)
        ``ztilde_k`` of each run (scalar output).
    v : ndarray, shape (N,)
    gamma : float

    Returns
    -------
    dict
        ``curve_z``, ``curve_v`` (N,) (the two sums over ``k``), ``sum_E_z2``,
        ``gamma2_sum_v2`` (their final values), ``sum_E_z2_stderr`` (standard error of the
        first over runs), ``inequality_holds`` (at every ``k``), ``gamma_needed`` (the
        smallest gamma for which it holds).
    """
    sum_z = np.cumsum(np.mean(z_err**2, axis=0))
    sum_v = np.cumsum(v**2)
    per_run = np.sum(z_err**2, axis=1)
    se = float(np.std(per_run, ddof=1) / np.sqrt(len(per_run))) if len(per_run) > 1 else 0.0
    return {"curve_z": sum_z, "curve_v": gamma**2 * sum_v,
            "sum_E_z2": float(sum_z[-1]), "gamma2_sum_v2": float(gamma**2 * sum_v[-1]),
            "sum_E_z2_stderr": se,
            "inequality_holds": bool(np.all(sum_z <= gamma**2 * sum_v)),
            "gamma_needed": float(np.sqrt(np.max(sum_z / sum_v)))}


# ----------------------------------------------------------------- Corollary 3
def quadratic_conditions_values(x: npt.ArrayLike, xhat: npt.ArrayLike, gamma: float, *,
                                printed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Left-hand sides of Corollary 3's (35) and (36) for Example 5.1 with ``Q1 = Q2 = I``.

    Parameters
    ----------
    x, xhat : array_like, shape (..., 2)
        Grid points (broadcast against each other).
    gamma : float
    printed : bool
        Evaluate the conditions as printed (without the noise terms ``h2``, ``f2`` and with
        ``+ xhat'Q2 xhat``) instead of the corrected ones (module docstring).

    Returns
    -------
    c35 : ndarray, shape (...)
        (35)'s left-hand side (a scalar: ``n_v = 1``); must be ``<= 0``.
    c36 : ndarray, shape (...)
        (36)'s left-hand side; must be ``<= 0``.
    """
    x, x1, x2 = _split(x)
    xhat = np.asarray(xhat, dtype=float)
    g2 = float(gamma) ** 2
    h1 = np.stack([0.1 * x1, np.zeros_like(x1)], axis=-1)
    h2 = np.stack([0.5 * x2, 0.5 * np.sin(x2)], axis=-1)
    ghat_g2 = 0.5 * np.sin(x)  # ghat = 0.5 I, g2 = [sin x1; sin x2]
    noise35 = 0.0 if printed else np.sum(h2**2, axis=-1)
    c35 = 2.0 * (np.sum(h1**2, axis=-1) + noise35 + np.sum(ghat_g2**2, axis=-1)) - g2
    f1 = drift(x)
    filt = 0.5 * xhat + 0.25 * x  # fhat + ghat g1
    sign = 1.0 if printed else -1.0
    m = output(x)
    mhat = output(xhat)
    c36 = (2.0 * (np.sum(f1**2, axis=-1) + np.sum(filt**2, axis=-1))
           - np.sum(x**2, axis=-1) + sign * np.sum(xhat**2, axis=-1)
           + 2.0 * m**2 + 2.0 * mhat**2)
    return np.broadcast_to(c35, c36.shape).copy(), c36


def state_grid(halfwidth: float, points: int) -> tuple[np.ndarray, np.ndarray]:
    """A regular grid of ``(x, xhat)`` on ``[-halfwidth, halfwidth]^4``.

    Returns
    -------
    x, xhat : ndarray, shape (points^4, 2)
    """
    if not (np.isfinite(halfwidth) and halfwidth > 0) or int(points) < 2:
        raise ValueError(f"halfwidth must be positive and points >= 2, got {halfwidth}, "
                         f"{points}")
    axis = np.linspace(-halfwidth, halfwidth, int(points))
    mesh = np.stack(np.meshgrid(axis, axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 4)
    return mesh[:, :2], mesh[:, 2:]


def quadratic_conditions_check(gamma: float, halfwidth: float = 2.0, points: int = 21, *,
                               printed: bool = False) -> dict[str, float | list[float] | None]:
    """Largest violation of Corollary 3's (35)-(36) on the grid :func:`state_grid`.

    Returns
    -------
    dict
        ``max_violation`` (the larger of the two maxima, ``<= 0`` means both hold on the
        grid), ``max_35``, ``max_36``, ``argmax_36`` (``[x1, x2, xhat1, xhat2]``),
        ``fraction_violated_36``, ``gamma_needed_35`` (smallest gamma for (35) on the grid),
        ``halfwidth``, ``points``, ``printed``.
    """
    x, xhat = state_grid(halfwidth, points)
    c35, c36 = quadratic_conditions_values(x, xhat, gamma, printed=printed)
    c35_0, _ = quadratic_conditions_values(x, xhat, 0.0, printed=printed)
    i36 = int(np.argmax(c36))
    return {
        "max_violation": float(max(c35.max(), c36.max())),
        "max_35": float(c35.max()),
        "max_36": float(c36.max()),
        "argmax_36": [*map(float, x[i36]), *map(float, xhat[i36])],
        "fraction_violated_36": float(np.mean(c36 > 0)),
        "hessian_36_max_eig_at_0": quadratic_conditions_origin_curvature(printed=printed),
        "gamma_needed_35": float(np.sqrt(max(c35_0.max(), 0.0))),
        "halfwidth": float(halfwidth),
        "points": int(points),
        "printed": bool(printed),
    }


def quadratic_conditions_origin_curvature(*, printed: bool = False, eps: float = 1e-4) -> float:
    """Largest eigenvalue of the Hessian of (36)'s left-hand side at ``eta = 0``.

    (36) vanishes at 0; a positive eigenvalue means it is violated along that direction
    arbitrarily close to the origin (central differences, step ``eps``).
    """
    basis = np.eye(4)
    zero = np.zeros(4)

    def c36(p: np.ndarray) -> float:
        return float(quadratic_conditions_values(p[:2], p[2:], 0.0, printed=printed)[1])

    H = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            ei, ej = eps * basis[i], eps * basis[j]
            H[i, j] = (c36(zero + ei + ej) - c36(zero + ei - ej) - c36(zero - ei + ej)
                       + c36(zero - ei - ej)) / (4 * eps * eps)
    return float(np.linalg.eigvalsh(0.5 * (H + H.T))[-1])


def hji_values(x: npt.ArrayLike, xhat: npt.ArrayLike, v: npt.ArrayLike,
               gamma: float) -> np.ndarray:
    """``H(eta, v) - gamma^2 v^2 = E V(eta+) - V(eta) + |z - zhat|^2 - gamma^2 v^2`` of (27)
    for (49)-(50) with ``V = |x|^2 + |xhat|^2``.

    Exact: with ``x+ = a + b w``, ``xhat+ = c`` (``w`` scalar, unit variance, zero mean),
    ``E V(eta+) = |a|^2 + |b|^2 + |c|^2``. (27) must hold for every ``eta`` and every ``v``.

    Parameters
    ----------
    x, xhat : array_like, shape (..., 2)
    v : array_like, shape (...)
    gamma : float

    Returns
    -------
    ndarray, shape (...)
        Must be ``<= 0`` everywhere for Corollary 2.
    """
    x, x1, x2 = _split(x)
    xhat = np.asarray(xhat, dtype=float)
    v = np.asarray(v, dtype=float)
    a = drift(x) + np.stack(np.broadcast_arrays(0.1 * v * x1, np.zeros_like(v * x1)), axis=-1)
    b = np.stack(np.broadcast_arrays(0.5 * x2 * np.sin(v), 0.5 * v * np.sin(x2)), axis=-1)
    c = filter_step(xhat, measure(x, v))
    ev = np.sum(a**2, axis=-1) + np.sum(b**2, axis=-1) + np.sum(c**2, axis=-1)
    V = np.sum(x**2, axis=-1) + np.sum(xhat**2, axis=-1)
    zt = output(x) - output(xhat)
    return ev - V + zt**2 - float(gamma) ** 2 * v**2


def hji_check(gamma: float, halfwidth: float = 2.0, points: int = 13,
              v_values: npt.ArrayLike | None = None) -> dict[str, float | list[float]]:
    """Largest value of :func:`hji_values` on the state grid times a set of ``v`` (a sample of
    (27), which must hold everywhere).

    ``v_values`` default: 11 values in ``[0, 2]`` (the range of the paper's ``v_k``; (27)
    must hold for every real ``v``, so pass a wider set to test it).

    Returns
    -------
    dict
        ``max_violation``, ``argmax`` (``[x1, x2, xhat1, xhat2, v]``),
        ``fraction_violated``, ``halfwidth``, ``points``.
    """
    x, xhat = state_grid(halfwidth, points)
    vs = np.linspace(0.0, 2.0, 11) if v_values is None else np.asarray(v_values, dtype=float)
    vals = hji_values(x[:, None, :], xhat[:, None, :], vs[None, :], gamma)
    i, j = np.unravel_index(int(np.argmax(vals)), vals.shape)
    return {
        "max_violation": float(vals.max()),
        "argmax": [*map(float, x[i]), *map(float, xhat[i]), float(vs[j])],
        "fraction_violated": float(np.mean(vals > 0)),
        "halfwidth": float(halfwidth),
        "points": int(points),
        "v_range": [float(vs.min()), float(vs.max())],
        "v_points": int(vs.size),
    }


def output_lower_bound_check() -> dict[str, object]:
    """Whether (26), ``|ztilde(eta, 0)|^2 >= W(eta)`` with ``W`` positive and radially
    unbounded, can hold for (49)-(50).

    ``ztilde(eta, 0) = m(x) - mhat(xhat)`` is linear here, ``c . eta`` with ``c`` read off
    :func:`output` at the unit vectors, so ``|ztilde|^2 = eta' (c c') eta``. (26) needs it
    positive for every ``eta != 0``: ``c c'`` positive definite, impossible for a rank-one
    matrix in four dimensions. The eigen-decomposition gives the smallest value of
    ``|ztilde|^2`` on the unit sphere and the directions where it vanishes.

    Returns
    -------
    dict
        ``c`` (4,), ``min_on_unit_sphere``, ``null_space_dim``, ``null_direction`` (4,)
        (a unit ``eta`` with ``ztilde(eta, 0) = 0``), ``possible`` (bool).
    """
    basis = np.eye(4)
    c = output(basis[:, :2]) - output(basis[:, 2:])
    M = np.outer(c, c)
    eig, vec = np.linalg.eigh(M)
    tol = 1e-12 * max(float(eig[-1]), 1e-300)
    null = int(np.sum(eig <= tol))
    return {"c": c.tolist(), "min_on_unit_sphere": float(eig[0]), "null_space_dim": null,
            "null_direction": vec[:, 0].tolist(), "possible": bool(eig[0] > tol)}


# the names docs/references.md printed before the rename, for one release
corollary3_values = deprecated_alias(quadratic_conditions_values, "corollary3_values")
condition26_check = deprecated_alias(output_lower_bound_check, "condition26_check")
