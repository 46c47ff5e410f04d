"""Polynomial system models of degree <= 3 and the finite-escape test shared by their users.

Reference: M. Basin, P. Shi, D. Calderon-Alvarez, "Central suboptimal H-infinity filter design
for nonlinear polynomial systems", eqs.
(1)-(4) and the polynomial of Theorem 1::

    dx/dt = f(x, t) + B(t) w(t) + E(t) u(t)                                  (1)
    y     = C(t) x + D(t) w(t)                                               (2)
    z     = L(t) x                                                           (3)
    f(x, t) = a0(t) + a1(t) x + a2(t) x x^T + a3(t) x x x^T

in summation form ``f_k = a0_k + sum_i a1_ki x_i + sum_ij a2_kij x_i x_j
+ sum_ijl a3_kijl x_i x_j x_l``. The input term ``E u`` is an extension (the paper has no
control input; ``E = None`` is the paper's system).

Only the part of ``a2`` symmetric in its last two indices (of ``a3``: last three) enters
``f``; :meth:`PolynomialModel.at` returns the symmetrized tensors, for which the closed
forms of Theorem 1 (14)-(15) hold for any tensor the user gives.

Units: time in seconds; the arrays are ``float64`` and carry the units of the user's system.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from itertools import permutations

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, TimeArg, TimeFunction, readonly
from filters.errors import FiniteEscapeError

__all__ = ["EscapeTest", "PolynomialCoefficients", "PolynomialModel"]

CoefArg = TimeArg
"""A constant array or a function ``t_s -> array`` (time-varying coefficient)."""


def symmetrize_tensor(a: FloatArray) -> FloatArray:
    """Average of ``a`` over all permutations of its trailing axes (all but the first).

    Parameters
    ----------
    a : numpy.ndarray, shape (n, n, ..., n)
        ``a2`` (3-D) or ``a3`` (4-D) coefficient tensor.

    Returns
    -------
    numpy.ndarray, same shape
        The tensor defining the same polynomial, symmetric in its trailing indices.
    """
    n = a.shape[0]
    idx = _permutation_index(n, a.ndim - 1)
    flat = a.reshape(n, -1)
    # the mean over the permutations (np.add.reduce / count is what ndarray.mean computes)
    return (np.add.reduce(flat[:, idx], axis=1) / idx.shape[0]).reshape(a.shape)


@lru_cache(maxsize=16)
def _permutation_index(n: int, order: int) -> npt.NDArray[np.intp]:
    """Flat indices ``(order!, n^order)``: row ``p`` maps a flattened trailing block to its
    axis permutation ``p`` (so ``flat[:, idx].mean(axis=1)`` symmetrizes)."""
    base = np.arange(n**order).reshape((n,) * order)
    return np.array([base.transpose(p).ravel() for p in permutations(range(order))])


@dataclass(frozen=True, slots=True)
class PolynomialCoefficients:
    """All coefficients of a :class:`PolynomialModel` at one time ``t``.

    Attributes
    ----------
    t : float
        Time in s.
    a0 : numpy.ndarray, shape (n,)
    a1 : numpy.ndarray, shape (n, n)
    a2 : numpy.ndarray, shape (n, n, n), or None
        Symmetric in the last two indices; ``None`` when the model has no quadratic term.
    a3 : numpy.ndarray, shape (n, n, n, n), or None
        Symmetric in the last three indices; ``None`` without a cubic term.
    B : numpy.ndarray, shape (n, p)
    C : numpy.ndarray, shape (m, n)
    D : numpy.ndarray, shape (m, p)
    L : numpy.ndarray, shape (q, n)
    E : numpy.ndarray, shape (n, k), or None
    """

    t: float
    a0: FloatArray
    a1: FloatArray
    a2: FloatArray | None
    a3: FloatArray | None
    B: FloatArray
    C: FloatArray
    D: FloatArray
    L: FloatArray
    E: FloatArray | None

    def f(self, x: npt.ArrayLike) -> FloatArray:
        """The polynomial ``f(x, t)``, shape ``(..., n)`` for ``x`` of shape ``(..., n)``."""
        x = np.asarray(x, dtype=np.float64)
        out = self.a0 + x @ self.a1.T
        if self.a2 is not None:
            out = out + np.einsum("kij,...i,...j->...k", self.a2, x, x)
        if self.a3 is not None:
            out = out + np.einsum("kijl,...i,...j,...l->...k", self.a3, x, x, x)
        return out

    def jacobian(self, x: npt.ArrayLike) -> FloatArray:
        """``df/dx = a1 + 2 a2 x + 3 a3 x x^T``, shape ``(..., n, n)`` (row k = df_k/dx)."""
        x = np.asarray(x, dtype=np.float64)
        J = np.broadcast_to(self.a1, (*x.shape[:-1], *self.a1.shape))
        if self.a2 is not None:
            J = J + 2.0 * np.einsum("kij,...i->...kj", self.a2, x)
        if self.a3 is not None:
            J = J + 3.0 * np.einsum("kijl,...i,...j->...kl", self.a3, x, x)
        return np.array(J)


class PolynomialModel:
    """Polynomial system of degree <= 3, Basin, Shi & Calderon-Alvarez, eqs. (1)-(4).

    Parameters
    ----------
    a0 : array_like, shape (n,), or callable ``t -> (n,)``, or None
        Constant term (``None``: zero).
    a1 : array_like, shape (n, n), or callable, or None
        Linear term (``None``: zero).
    a2 : array_like, shape (n, n, n), or callable, or None
        Quadratic term ``f_k += sum_ij a2[k, i, j] x_i x_j`` (``None``: zero).
    a3 : array_like, shape (n, n, n, n), or callable, or None
        Cubic term ``f_k += sum_ijl a3[k, i, j, l] x_i x_j x_l`` (``None``: zero).
    B : array_like, shape (n, p), or callable
        Disturbance input of the state (1).
    C : array_like, shape (m, n), or callable
        Observation matrix (2).
    D : array_like, shape (m, p), or callable
        Disturbance input of the observation (2).
    L : array_like, shape (q, n), or callable
        Output to be estimated (3).
    E : array_like, shape (n, k), or callable, or None
        Control input (extension; the paper has none).
    n : int, optional
        State dimension; needed only if no argument fixes it.
    t0 : float
        Time at which callables are first evaluated (for validation), s.

    Attributes
    ----------
    n, p, m, q, k : int
        Dimensions of the state, disturbance, observation, output and input.
    degree : int
        Highest degree with a (possibly) non-zero coefficient.
    constant : bool
        No coefficient is a callable.
    constant_matrices : bool
        ``B``, ``C``, ``D``, ``L`` and ``E`` are constant (the ``a_i`` may vary).

    Raises
    ------
    ValueError
        Inconsistent shapes or non-finite entries, naming the argument.

    Notes
    -----
    A coefficient given as an all-zero constant is dropped (``None`` in
    :class:`PolynomialCoefficients`), so lower degrees cost nothing. Callables are validated
    (shape, finiteness) at every evaluation.
    """

    def __init__(
        self,
        a0: CoefArg | None = None,
        a1: CoefArg | None = None,
        a2: CoefArg | None = None,
        a3: CoefArg | None = None,
        *,
        B: CoefArg,
        C: CoefArg,
        D: CoefArg,
        L: CoefArg,
        E: CoefArg | None = None,
        n: int | None = None,
        t0: float = 0.0,
    ) -> None:
        t0 = float(t0)
        if not math.isfinite(t0):
            raise ValueError(f"t0 must be a finite time in s, got {t0!r}")
        self._t0 = t0
        self._args = {"a0": a0, "a1": a1, "a2": a2, "a3": a3, "B": B, "C": C, "D": D, "L": L,
                      "E": E}
        B_ = TimeFunction("B", B, (None, None), t0)
        n_b = B_.shape[0]
        if n is not None and (int(n) != n or n < 1):
            raise ValueError(f"n must be a positive integer, got {n!r}")
        if n is not None and n != n_b:
            raise ValueError(f"B must have n = {n} rows, got shape {B_.shape}")
        n = n_b
        if n < 1:
            raise ValueError(f"B must have shape (n, p) with n >= 1, got shape {B_.shape}")
        p = B_.shape[1]
        C_ = TimeFunction("C", C, (None, n), t0)
        m = C_.shape[0]
        if m < 1:
            raise ValueError(f"C must have at least one row, got shape {C_.shape}")
        self._B, self._C = B_, C_
        self._D = TimeFunction("D", D, (m, p), t0)
        self._L = TimeFunction("L", L, (None, n), t0)
        self._E = None if E is None else TimeFunction("E", E, (n, None), t0)
        shapes = {"a0": (n,), "a1": (n, n), "a2": (n, n, n), "a3": (n, n, n, n)}
        coefs: dict[str, TimeFunction | None] = {}
        for name, arg in (("a0", a0), ("a1", a1), ("a2", a2), ("a3", a3)):
            c = None if arg is None else TimeFunction(name, arg, shapes[name], t0)
            if c is not None and c.constant and not np.any(c.value):
                c = None  # an all-zero constant contributes nothing
            coefs[name] = c
        self._a0, self._a1, self._a2, self._a3 = (coefs[k] for k in ("a0", "a1", "a2", "a3"))
        self.n, self.p, self.m, self.q = n, p, m, self._L.shape[0]
        self.k = 0 if self._E is None else self._E.shape[1]
        self.degree = max([0] + [d for d, c in enumerate((self._a0, self._a1, self._a2,
                                                          self._a3)) if c is not None])
        parts = (self._a0, self._a1, self._a2, self._a3, self._B, self._C, self._D, self._L,
                 self._E)
        self.constant = all(c is None or c.constant for c in parts)
        self.constant_matrices = all(c is None or c.constant for c in parts[4:])
        self._zero0 = readonly(np.zeros(n))
        self._zero1 = readonly(np.zeros((n, n)))
        # constant symmetrized tensors are computed once
        self._a2s = None if self._a2 is None or not self._a2.constant else readonly(
            symmetrize_tensor(self._a2.value))
        self._a3s = None if self._a3 is None or not self._a3.constant else readonly(
            symmetrize_tensor(self._a3.value))
        self._const: PolynomialCoefficients | None = self._evaluate(t0) if self.constant \
            else None

    def __repr__(self) -> str:
        return (f"PolynomialModel(n={self.n}, p={self.p}, m={self.m}, q={self.q}, k={self.k}, "
                f"degree={self.degree}, constant={self.constant})")

    def replace(self, **changes: CoefArg | None) -> PolynomialModel:
        """A copy with some arguments replaced (e.g. ``model.replace(L=[[1.0, 0.0]])``).

        Parameters
        ----------
        **changes
            Any of ``a0, a1, a2, a3, B, C, D, L, E``.

        Returns
        -------
        PolynomialModel
        """
        unknown = set(changes) - set(self._args)
        if unknown:
            raise ValueError(f"unknown model arguments {sorted(unknown)}; expected among "
                             f"{sorted(self._args)}")
        args = {**self._args, **changes}
        return PolynomialModel(**args, n=self.n, t0=self._t0)  # type: ignore[arg-type]

    @property
    def varying(self) -> tuple[str, ...]:
        """Names of the polynomial coefficients (among ``a0``..``a3``) given as callables."""
        return tuple(name for name, c in (("a0", self._a0), ("a1", self._a1),
                                          ("a2", self._a2), ("a3", self._a3))
                     if c is not None and not c.constant)

    def coefficient(self, name: str, t: float) -> FloatArray | None:
        """One polynomial coefficient at time ``t`` as given (validated, not symmetrized).

        Parameters
        ----------
        name : {"a0", "a1", "a2", "a3"}
        t : float
            Time in s.

        Returns
        -------
        numpy.ndarray, shape (n,), (n, n), (n, n, n) or (n, n, n, n), or None
            ``None`` for an absent (or all-zero constant) coefficient.
        """
        if name not in ("a0", "a1", "a2", "a3"):
            raise ValueError(f"name must be one of ['a0', 'a1', 'a2', 'a3'], got {name!r}")
        c = getattr(self, "_" + name)
        return None if c is None else c(t)

    def at(self, t: float) -> PolynomialCoefficients:
        """All coefficients at time ``t`` (s), tensors symmetrized, absent terms ``None``."""
        if self._const is not None:
            return self._const
        return self._evaluate(float(t))

    def _evaluate(self, t: float) -> PolynomialCoefficients:
        a2 = None
        if self._a2 is not None:
            a2 = self._a2s if self._a2s is not None else symmetrize_tensor(self._a2(t))
        a3 = None
        if self._a3 is not None:
            a3 = self._a3s if self._a3s is not None else symmetrize_tensor(self._a3(t))
        return PolynomialCoefficients(
            t=t,
            a0=self._zero0 if self._a0 is None else self._a0(t),
            a1=self._zero1 if self._a1 is None else self._a1(t),
            a2=a2, a3=a3, B=self._B(t), C=self._C(t), D=self._D(t), L=self._L(t),
            E=None if self._E is None else self._E(t),
        )

    def f(self, x: npt.ArrayLike, t: float) -> FloatArray:
        """``f(x, t)``, shape ``(..., n)``."""
        return self.at(t).f(x)

    def jacobian(self, x: npt.ArrayLike, t: float) -> FloatArray:
        """``df/dx (x, t)``, shape ``(..., n, n)``."""
        return self.at(t).jacobian(x)


@dataclass(frozen=True, slots=True)
class EscapeTest:
    """Detect finite escape of an integrated quantity (state, estimate, gain matrix).

    A quantity (array of shape ``(..., d)`` or ``(..., d, d)``) has escaped when, after an
    integration step, some batch element

    * has a non-finite entry or an entry larger than ``bound`` in magnitude (**bound test**),
      or
    * has ``max|entry| > growth_floor`` and its ``max|entry|`` grew by more than
      ``growth_rtol`` (relative) in that one step (**growth test**).

    For a finite escape ``q' ~ c q^2``, ``1/q`` falls linearly to zero; a relative growth
    ``r`` per step ``h`` then means the blow-up is about ``h / r`` ahead (10 steps for the
    default 0.1). Exponential growth that fast is not resolved by the integrator either, so
    the test also stops integrations that have become meaningless. The error's message
    gives the blow-up time extrapolated from the last two steps.

    Attributes
    ----------
    bound : float
        Largest admissible magnitude (default 1e8).
    growth_rtol : float
        Largest admissible relative growth of ``max|entry|`` in one integration step.
    growth_floor : float
        The growth test applies only above this magnitude (small quantities may grow fast
        relative to themselves, e.g. an estimate leaving 0).
    """

    bound: float = 1e8
    growth_rtol: float = 0.1
    growth_floor: float = 1e2

    def __post_init__(self) -> None:
        for name in ("bound", "growth_rtol", "growth_floor"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite float, got {value!r}")

    @staticmethod
    def magnitude(value: FloatArray, core_ndim: int) -> FloatArray:
        """``max|entry|`` over the trailing ``core_ndim`` axes (NaN propagates), shape (...)."""
        if value.ndim == core_ndim:  # one quantity
            return np.maximum.reduce(np.abs(value), axis=None)
        axes = tuple(range(-core_ndim, 0))
        return np.abs(value).max(axis=axes)

    def check(self, quantity: str, previous: FloatArray | float, value: FloatArray,
              *, time: float, step_s: float, core_ndim: int) -> FloatArray:
        """Raise :class:`~filters.errors.FiniteEscapeError` if ``value`` escaped.

        Parameters
        ----------
        quantity : str
            Name carried by the error (``"x"``, ``"P"``, ``"state"``).
        previous : numpy.ndarray, shape (...), or float
            ``max|entry|`` before the step (from the last call or :meth:`magnitude`).
        value : numpy.ndarray, shape (..., d) or (..., d, d)
            The quantity after the step.
        time : float
            Time at the end of the step, s (carried by the error).
        step_s : float
            Length of the step, s (for the extrapolated blow-up time).
        core_ndim : int
            1 for vectors, 2 for matrices.

        Returns
        -------
        numpy.ndarray, shape (...)
            ``max|entry|`` of ``value``, to pass as ``previous`` next time.
        """
        mag = self.magnitude(value, core_ndim)
        if mag.ndim == 0:  # one quantity: the same tests on Python floats (fast path)
            m, p = float(mag), float(previous)
            if m <= self.bound and not (m > self.growth_floor
                                        and m > p * (1.0 + self.growth_rtol)):
                return mag
        else:  # a batch: the same tests on the largest magnitude first (fast path)
            top = float(mag.max())  # NaN fails both comparisons below
            if top <= self.bound and (top <= self.growth_floor or not np.any(
                    mag > np.maximum(np.multiply(previous, 1.0 + self.growth_rtol),
                                     self.growth_floor))):
                return mag
        bad = ~(mag <= self.bound)  # NaN compares False
        if np.any(bad):
            worst = float(np.max(np.where(np.isnan(mag), np.inf, mag)))
            raise FiniteEscapeError(
                f"{quantity}{_where(bad)} escaped: max |entry| = {worst:.6g} exceeds the bound "
                f"{self.bound:.3g} (bound test)", time=time, quantity=quantity,
                value=np.array(value))
        prev = np.asarray(previous, dtype=np.float64)
        grow = (mag > self.growth_floor) & (mag > prev * (1.0 + self.growth_rtol))
        if np.any(grow):
            i = np.unravel_index(int(np.argmax(np.where(grow, mag / np.maximum(prev, 1e-300),
                                                        0.0))), grow.shape) if grow.ndim else ()
            p, q = float(np.broadcast_to(prev, grow.shape)[i]), float(mag[i])
            ahead = step_s * p / (q - p)
            raise FiniteEscapeError(
                f"{quantity}{_where(grow)} escapes: max |entry| grew from {p:.6g} to {q:.6g} "
                f"(+{q / p - 1:.0%}) in one step of {step_s:.3g} s (growth test, limit "
                f"+{self.growth_rtol:.0%}); extrapolated blow-up at t ~ {time + ahead:.6g} s",
                time=time, quantity=quantity, value=np.array(value))
        return mag


def _where(mask: npt.NDArray[np.bool_]) -> str:
    """The first batch index where ``mask`` holds (empty for a single quantity)."""
    if mask.ndim == 0:
        return ""
    idx = tuple(int(i[0]) for i in np.nonzero(mask))
    return f"[batch index {idx}]"
