"""Linear-Gaussian system models in continuous and discrete time.

Continuous time (:class:`LinearSystem`), Ito form::

    dx = (A x + B u) dt + dw,      E[dw dw^T] = Q dt   (Q: process-noise intensity)
    dy = (C x + D u) dt + dv,      E[dv dv^T] = R dt   (R: measurement-noise intensity)

Discrete time (:class:`DiscreteLinearSystem`)::

    x_{k+1} = F x_k + B u_k + w_k,     w_k ~ N(0, Q)
    y_k     = H x_k + D u_k + v_k,     v_k ~ N(0, R)

Shapes: state ``n``, measurement ``m``, input ``k`` (``k = 0``: no input, ``B`` is
stored with shape ``(n, 0)``). Times are in seconds. All matrices are stored as
read-only ``float64`` copies; the dataclasses are frozen and compare by identity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from filters._linalg import (
    FloatArray,
    matrix,
    positive_time,
    readonly,
    symmetric_psd,
    van_loan,
    zoh,
)

__all__ = ["DiscreteLinearSystem", "LinearSystem"]


def _validate_common(
    obj: object, names: tuple[str, str, str], Bv: object, Dv: object, Qv: object, Rv: object
) -> None:
    """Validate and freeze the fields shared by both system classes (sets attributes)."""
    a_name, _, c_name = names
    A = matrix(a_name, getattr(obj, a_name), (None, None), what="a finite square matrix")
    n = A.shape[0]
    if A.shape != (n, n) or n == 0:
        raise ValueError(
            f"{a_name} must be a finite square matrix with shape (n, n), n >= 1, "
            f"got shape {A.shape}"
        )
    B = np.zeros((n, 0)) if Bv is None else matrix("B", Bv, (n, None), labels=("n", "k"))
    k = B.shape[1]
    C = matrix(c_name, getattr(obj, c_name), (None, n), labels=("m", "n"))
    m = C.shape[0]
    if m == 0:
        raise ValueError(f"{c_name} must have shape (m, {n}) with m >= 1, got shape {C.shape}")
    D = np.zeros((m, k)) if Dv is None else matrix("D", Dv, (m, k))
    Q = symmetric_psd("Q", Qv, n, definite=False)
    R = symmetric_psd("R", Rv, m, definite=True)
    for name, arr in ((a_name, A), ("B", B), (c_name, C), ("D", D), ("Q", Q), ("R", R)):
        object.__setattr__(obj, name, readonly(arr))


@dataclass(frozen=True, eq=False)
class LinearSystem:
    """Continuous-time linear-Gaussian system (noise given as intensities).

    Parameters
    ----------
    A : array_like, shape (n, n)
        Drift matrix, 1/s.
    B : array_like, shape (n, k), or None
        Input matrix; ``None`` means no input and is stored as shape ``(n, 0)``.
    C : array_like, shape (m, n)
        Output matrix of the observation rate ``dy/dt``.
    Q : array_like, shape (n, n)
        Process-noise intensity ``b b^T`` (symmetric PSD): ``Cov[w(t+dt) - w(t)] = Q dt``.
    R : array_like, shape (m, m)
        Measurement-noise intensity ``h h^T`` (symmetric positive definite).
    D : array_like, shape (m, k), or None
        Direct feedthrough into the observation rate; ``None`` means zero.

    Raises
    ------
    ValueError
        Naming the offending argument and the expected shape/property.
    """

    A: FloatArray
    B: FloatArray | None
    C: FloatArray
    Q: FloatArray
    R: FloatArray
    D: FloatArray | None = None

    def __post_init__(self) -> None:
        _validate_common(self, ("A", "B", "C"), self.B, self.D, self.Q, self.R)

    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.C.shape[0]

    @property
    def k(self) -> int:
        """Input dimension (0 if the system has no input)."""
        return self.B.shape[1]  # type: ignore[union-attr]

    def discretize(self, dt_s: float) -> DiscreteLinearSystem:
        """Sample the system with period ``dt_s`` (zero-order-hold input).

        Parameters
        ----------
        dt_s : float
            Sample period in seconds (> 0).

        Returns
        -------
        DiscreteLinearSystem
            ``F = exp(A dt)`` (n, n); ``B_d = int_0^dt exp(A s) ds B`` (n, k), exact
            ZOH; ``H = C`` (m, n); ``D_d = D`` (m, k);
            ``Q_d = int_0^dt exp(A s) Q exp(A^T s) ds`` (n, n) by Van Loan's method;
            ``R_d = R / dt_s`` (m, m); ``dt_s`` recorded.

        Notes
        -----
        Measurement convention: a discrete measurement ``y_k`` is a sample of the
        averaged observation rate ``(y(t_k) - y(t_k - dt)) / dt`` and is modeled as
        ``H x_k + D u + v_k``, so **sampled variance = intensity / dt**
        (``R_d = R / dt_s``). The filters treat ``y_k`` in the same units as
        ``dy/dt``.
        """
        dt = positive_time("dt_s", dt_s)
        F, Bd = zoh(self.A, self.B, dt)  # type: ignore[arg-type]
        Qd = van_loan(self.A, self.Q, dt)
        return DiscreteLinearSystem(F=F, B=Bd, H=self.C, Q=Qd, R=self.R / dt, dt_s=dt, D=self.D)


@dataclass(frozen=True, eq=False)
class DiscreteLinearSystem:
    """Discrete-time linear-Gaussian system (noise given as covariances).

    Parameters
    ----------
    F : array_like, shape (n, n)
        State transition matrix.
    B : array_like, shape (n, k), or None
        Input matrix; ``None`` is stored as shape ``(n, 0)``.
    H : array_like, shape (m, n)
        Measurement matrix.
    Q : array_like, shape (n, n)
        Process-noise covariance (symmetric PSD).
    R : array_like, shape (m, m)
        Measurement-noise covariance (symmetric positive definite).
    dt_s : float or None
        Sample period in seconds, if known.
    D : array_like, shape (m, k), or None
        Direct feedthrough ``y_k = H x_k + D u_k + v_k``; ``None`` means zero.

    Raises
    ------
    ValueError
        Naming the offending argument and the expected shape/property.
    """

    F: FloatArray
    B: FloatArray | None
    H: FloatArray
    Q: FloatArray
    R: FloatArray
    dt_s: float | None = None
    D: FloatArray | None = None

    def __post_init__(self) -> None:
        _validate_common(self, ("F", "B", "H"), self.B, self.D, self.Q, self.R)
        if self.dt_s is not None:
            object.__setattr__(self, "dt_s", positive_time("dt_s", self.dt_s))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.F.shape[0]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.H.shape[0]

    @property
    def k(self) -> int:
        """Input dimension (0 if the system has no input)."""
        return self.B.shape[1]  # type: ignore[union-attr]
