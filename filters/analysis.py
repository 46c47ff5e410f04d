"""Analysis toolkit: performance measures of estimator runs and of linear filtering systems.

Usable on any filter, independent of how it was designed. Times are in seconds; frequencies
in rad/s (continuous time) or rad/sample (discrete time, in ``[0, pi]``); arrays are
``float64``.

Contents
--------
Trajectory measures
    :func:`noise_output_ratio` (the ``T`` of Basin, Elvira-Ceja & Sanchez).
Linear time-invariant systems ``x' = A x + B w``, ``z = C x + D w`` (or ``x(k+1) = ...``)
    :func:`hinf_norm` / :func:`hinf_norm_bounds`: H-infinity norm by bisection on the
    Hamiltonian (continuous) or symplectic (discrete) pencil, to a stated relative
    tolerance; :func:`sigma_max_response` for frequency sweeps;
    :func:`steady_state_covariance`: continuous or discrete Lyapunov equation.
Pole regions
    :class:`Parabola` (Wang & Fang's ``P(a, b)``, Fact 1 / (8)), :class:`LeftHalfPlane`,
    :class:`Disk` and :func:`unit_disk`; :func:`poles_in_region`.
Filters ``xhat' = G xhat + K y`` on plants with norm-bounded uncertainty
    :class:`UncertainPlant` (``[dA; dC] = [M1; M2] F N``, ``F^T F <= I``),
    :func:`error_system` (the augmented system (5) of Wang & Fang / (6) of Liu et al.),
    :func:`error_covariance`, :func:`uncertainty_samples` and
    :func:`robust_filter_analysis`: pole region, H-infinity norm and steady-state error
    variances at the vertices and on a grid of ``F``, with the worst case and where it occurs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
from scipy.integrate import cumulative_trapezoid
from scipy.linalg import eigvals, solve_continuous_lyapunov, solve_discrete_lyapunov

from filters._linalg import FloatArray, matrix, real_array, to_float_array
from filters.errors import FilterError

__all__ = [
    "Disk",
    "HinfNorm",
    "LeftHalfPlane",
    "Parabola",
    "PoleRegion",
    "RobustAnalysis",
    "UncertainPlant",
    "UnstableSystemError",
    "error_covariance",
    "error_system",
    "hinf_norm",
    "hinf_norm_bounds",
    "noise_output_ratio",
    "poles_in_region",
    "robust_filter_analysis",
    "sigma_max_response",
    "steady_state_covariance",
    "uncertainty_samples",
    "unit_disk",
]


def noise_output_ratio(
    t: npt.ArrayLike,
    z_err: npt.ArrayLike,
    w: npt.ArrayLike,
    x0: npt.ArrayLike,
    R: npt.ArrayLike,
) -> FloatArray:
    """Running noise-output ratio ``T`` of Basin et al. (attenuation condition (6)).

    ``T(t) = ||z - L m||_2 / (||w||_2^2 + x0^T R x0)^(1/2)`` with
    ``||f||_2^2 = int_{t[0]}^{t} f^T f ds``, evaluated at every sample time. The paper's
    filter guarantees ``T < gamma`` for the mean (noise-free) trajectory.

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing sample times, s.
    z_err : array_like, shape (N, q) or (N,)
        Output estimation error ``z - L m = L (x - m)`` at the sample times.
    w : array_like, shape (N, s) or (N,)
        Deterministic disturbance at the sample times.
    x0 : array_like, shape (n,)
        Initial state weighted in the denominator; Basin et al.'s (6) uses ``E[x(t0)]``.
    R : array_like, shape (n, n)
        Weight of ``x0`` (the ``R`` of (6), ``S(t0) = R^-1``).

    Returns
    -------
    numpy.ndarray, shape (N,)
        ``T`` over ``[t[0], t[k]]`` for each ``k``. Where the denominator is 0 the ratio
        is 0 if the numerator is 0 as well, ``inf`` otherwise.

    Raises
    ------
    ValueError
        On inconsistent shapes, non-finite input or non-increasing ``t``.

    Notes
    -----
    Both integrals use the trapezoid rule on the given samples
    (:func:`scipy.integrate.cumulative_trapezoid`), so ``T(t[0]) = 0`` unless
    ``x0^T R x0 = 0``.
    """
    ts = real_array(t, "t", finite=False)
    if ts.ndim != 1 or ts.size < 1:
        raise ValueError(f"t must have shape (N,), N >= 1, got shape {ts.shape}")
    N = ts.size

    def samples(name: str, value: npt.ArrayLike) -> FloatArray:
        arr = real_array(value, name, finite=False)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != N:
            raise ValueError(f"{name} must have shape ({N},) or ({N}, d), got shape "
                             f"{np.shape(value)}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} must be finite")
        return arr

    ze = samples("z_err", z_err)
    ws = samples("w", w)
    if not np.isfinite(ts).all() or np.any(np.diff(ts) <= 0.0):
        raise ValueError("t must be finite and strictly increasing")
    x = real_array(x0, "x0", finite=False)
    Rm = real_array(R, "R", finite=False)
    if x.ndim != 1 or Rm.shape != (x.size, x.size):
        raise ValueError(f"x0 must have shape (n,) and R shape (n, n), got {x.shape} and "
                         f"{Rm.shape}")
    weight = float(x @ Rm @ x)
    if not np.isfinite(weight):
        raise ValueError("x0 and R must be finite")
    num = cumulative_trapezoid(np.einsum("ij,ij->i", ze, ze), ts, initial=0.0)
    den = cumulative_trapezoid(np.einsum("ij,ij->i", ws, ws), ts, initial=0.0) + weight
    out = np.full(N, np.inf)
    pos = den > 0.0
    out[pos] = np.sqrt(num[pos] / den[pos])
    out[~pos & (num == 0.0)] = 0.0
    return out


# ====================================================================== LTI systems
class UnstableSystemError(FilterError):
    """A steady state or an H-infinity norm was asked of a system that is not stable.

    Attributes
    ----------
    eigenvalues : numpy.ndarray, shape (n,), complex
        Eigenvalues of the system matrix.
    """

    def __init__(self, message: str, eigenvalues: npt.NDArray[np.complex128]) -> None:
        super().__init__(message)
        self.eigenvalues = eigenvalues


#: Relative distance from the imaginary axis (unit circle) below which a pencil eigenvalue
#: is a candidate crossing; every candidate is confirmed by evaluating the frequency response.
_AXIS_TOL = 1e-6


def _lti(A: object, B: object, C: object, D: object | None) -> tuple[FloatArray, ...]:
    """Validate ``(A, B, C, D)``: shapes (n, n), (n, m), (p, n), (p, m); finite."""
    A_ = matrix("A", A, (None, None), what="a finite square matrix")
    n = A_.shape[0]
    if A_.shape != (n, n) or n == 0:
        raise ValueError(f"A must be a finite square matrix with shape (n, n), n >= 1, got "
                         f"shape {A_.shape}")
    B_ = matrix("B", B, (n, None), labels=("n", "m"))
    C_ = matrix("C", C, (None, n), labels=("p", "n"))
    D_ = (np.zeros((C_.shape[0], B_.shape[1])) if D is None
          else matrix("D", D, (C_.shape[0], B_.shape[1])))
    return A_, B_, C_, D_


def _is_stable(eig: npt.NDArray[np.complex128], discrete: bool) -> bool:
    return bool(np.all(np.abs(eig) < 1.0)) if discrete else bool(np.all(eig.real < 0.0))


def sigma_max_response(A: npt.ArrayLike, B: npt.ArrayLike, C: npt.ArrayLike,
                       D: npt.ArrayLike | None, frequencies: npt.ArrayLike, *,
                       discrete: bool = False) -> FloatArray:
    """Largest singular value of the frequency response at the given frequencies.

    Parameters
    ----------
    A, B, C, D : array_like, shapes (n, n), (n, m), (p, n), (p, m)
        ``D = None`` means zero.
    frequencies : array_like, shape (F,)
        rad/s (continuous: ``s = j w``; ``inf`` gives ``D``) or rad/sample (discrete:
        ``z = exp(j w)``).
    discrete : bool
        Discrete-time system.

    Returns
    -------
    numpy.ndarray, shape (F,)
        ``sigma_max(C (s I - A)^-1 B + D)``; ``inf`` where ``s`` is an eigenvalue of ``A``.
    """
    A_, B_, C_, D_ = _lti(A, B, C, D)
    w = np.atleast_1d(np.asarray(frequencies, dtype=np.float64))
    return np.array([_sigma(A_, B_, C_, D_, float(wi), discrete) for wi in w])


def _sigma(A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray, w: float,
           discrete: bool) -> float:
    if not discrete and math.isinf(w):
        return float(np.linalg.norm(D, 2)) if D.size else 0.0
    s = np.exp(1j * w) if discrete else 1j * w
    try:
        G = C @ np.linalg.solve(s * np.eye(A.shape[0]) - A, B) + D
    except np.linalg.LinAlgError:
        return math.inf
    if G.size == 0:
        return 0.0
    return float(np.linalg.svd(G, compute_uv=False)[0])


def _pencil(A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray, gamma: float,
            discrete: bool) -> tuple[FloatArray, FloatArray]:
    """Extended Hamiltonian (continuous) or symplectic (discrete) pencil ``(M, N)``.

    Unknowns ``(x, p, u, v)`` with ``G u = gamma v`` and ``G~ v = gamma u`` (``G~`` the
    para-Hermitian conjugate): ``lambda`` is a finite eigenvalue of ``M - lambda N`` on the
    imaginary axis (continuous) or the unit circle (discrete) iff ``gamma`` is a singular
    value of ``G`` at that frequency. Rows::

        continuous: s x = A x + B u,        s p = -A^T p - C^T v,
        discrete:   z x = A x + B u,          p = z (A^T p + C^T v),
        both:         0 = C x + D u - gamma v,  0 = B^T p + D^T v - gamma u.

    The pencil needs no inverse of ``A`` or of ``gamma^2 I - D^T D``.
    """
    n, m = B.shape
    p = C.shape[0]
    size = 2 * n + m + p
    M = np.zeros((size, size))
    Nm = np.zeros((size, size))
    x, q, u, v = slice(0, n), slice(n, 2 * n), slice(2 * n, 2 * n + m), slice(2 * n + m, size)
    M[x, x], M[x, u] = A, B
    Nm[x, x] = np.eye(n)
    if discrete:
        M[q, q] = np.eye(n)
        Nm[q, q], Nm[q, v] = A.T, C.T
    else:
        M[q, q], M[q, v] = -A.T, -C.T
        Nm[q, q] = np.eye(n)
    M[v, x], M[v, u], M[v, v] = C, D, -gamma * np.eye(p)
    M[u, q], M[u, v], M[u, u] = B.T, D.T, -gamma * np.eye(m)
    return M, Nm


def _crossing_frequencies(A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray,
                          gamma: float, discrete: bool) -> FloatArray:
    """Frequencies where the pencil has (numerically) an eigenvalue on the stability boundary."""
    M, Nm = _pencil(A, B, C, D, gamma, discrete)
    alpha, beta = eigvals(M, Nm, homogeneous_eigvals=True)
    finite = np.abs(beta) > 1e-13 * np.maximum(np.abs(alpha), 1e-300)
    lam = alpha[finite] / beta[finite]
    if discrete:
        on = np.abs(np.abs(lam) - 1.0) <= _AXIS_TOL
        freqs = np.abs(np.angle(lam[on]))
    else:
        on = np.abs(lam.real) <= _AXIS_TOL * np.maximum(1.0, np.abs(lam))
        freqs = np.abs(lam[on].imag)
    return np.unique(np.round(freqs, 14))


@dataclass(frozen=True)
class HinfNorm:
    """Result of :func:`hinf_norm_bounds`.

    Attributes
    ----------
    value : float
        ``(lower + upper) / 2``; ``inf`` for an unstable system.
    lower : float
        ``sigma_max`` of the response at ``peak_frequency`` (attained, so a certified lower
        bound).
    upper : float
        Smallest ``gamma`` tested whose pencil has no eigenvalue on the imaginary axis (unit
        circle). ``upper - lower <= rtol * lower`` on return.
    peak_frequency : float or None
        Frequency of ``lower`` (rad/s or rad/sample); ``inf`` if the peak is ``D`` at
        infinite frequency, ``None`` for an unstable or zero system.
    iterations : int
        Pencil eigenvalue problems solved.
    discrete : bool
    stable : bool
    """

    value: float
    lower: float
    upper: float
    peak_frequency: float | None
    iterations: int
    discrete: bool
    stable: bool


def hinf_norm_bounds(A: npt.ArrayLike, B: npt.ArrayLike, C: npt.ArrayLike,
                     D: npt.ArrayLike | None = None, *, discrete: bool = False,
                     rtol: float = 1e-6, max_iter: int = 200) -> HinfNorm:
    """H-infinity norm of ``C (s I - A)^-1 B + D`` (or ``z``) with certified bounds.

    Bisection on ``gamma`` (Boyd, Balakrishnan & Kabamba 1989; discrete: the symplectic
    pencil), accelerated as in Bruinsma & Steinbuch (1990): every ``gamma`` whose pencil
    has eigenvalues on the imaginary axis (unit circle) is confirmed by evaluating the
    response at those frequencies and at the midpoints between them, which also raises the
    lower bound; ``gamma`` without such eigenvalues is an upper bound. Any number of inputs
    and outputs.

    Parameters
    ----------
    A, B, C, D : array_like, shapes (n, n), (n, m), (p, n), (p, m)
        ``D = None`` means zero.
    discrete : bool
        Discrete-time system (norm over the unit circle).
    rtol : float
        Relative tolerance: ``upper - lower <= rtol * lower`` on return (> 0).
    max_iter : int
        Largest number of pencil eigenvalue problems.

    Returns
    -------
    HinfNorm
        ``value = inf`` (and ``stable = False``) if ``A`` is not Hurwitz (Schur).

    Raises
    ------
    ValueError
        On invalid shapes, non-finite entries or ``rtol <= 0``.
    FilterError
        If the tolerance is not reached in ``max_iter`` iterations.
    """
    A_, B_, C_, D_ = _lti(A, B, C, D)
    if not (np.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol must be a positive finite float, got {rtol!r}")
    eig = np.linalg.eigvals(A_)
    if not _is_stable(eig, discrete):
        return HinfNorm(math.inf, math.inf, math.inf, None, 0, discrete, False)
    if not np.any(B_) or not np.any(C_):
        d = float(np.linalg.norm(D_, 2)) if D_.size else 0.0
        return HinfNorm(d, d, d, math.inf if d > 0 else None, 0, discrete, True)

    # initial lower bound: zero and infinite frequency, pole frequencies, a coarse sweep
    if discrete:
        cand = np.concatenate([[0.0, np.pi], np.abs(np.angle(eig)),
                               np.linspace(0.0, np.pi, 17)])
    else:
        mags = np.abs(eig)
        cand = np.concatenate([[0.0, math.inf], mags, np.abs(eig.imag),
                               np.geomspace(1e-3, 1e3, 13) * max(float(mags.max()), 1e-12)])
    sig = np.array([_sigma(A_, B_, C_, D_, float(w), discrete) for w in cand])
    k = int(np.argmax(sig))
    lo, peak = float(sig[k]), float(cand[k])
    if lo == 0.0:
        return HinfNorm(0.0, 0.0, 0.0, None, 0, discrete, True)

    def test(gamma: float) -> tuple[bool, float, float]:
        """(gamma <= norm confirmed, best sigma found, its frequency)."""
        w = _crossing_frequencies(A_, B_, C_, D_, gamma, discrete)
        if w.size == 0:
            return False, 0.0, 0.0
        pts = np.concatenate([w, 0.5 * (w[1:] + w[:-1])])
        s = np.array([_sigma(A_, B_, C_, D_, float(x), discrete) for x in pts])
        j = int(np.argmax(s))
        return bool(s[j] >= gamma), float(s[j]), float(pts[j])

    iterations = 0
    hi = 2.0 * lo
    while True:  # find an upper bound
        iterations += 1
        above, s, w = test(hi)
        if s > lo:
            lo, peak = s, w
        if not above:
            break
        hi = 2.0 * max(hi, lo)
        if iterations >= max_iter:
            raise FilterError(f"H-infinity norm: no upper bound found in {max_iter} iterations")
    while hi - lo > rtol * lo:
        if iterations >= max_iter:
            raise FilterError(f"H-infinity norm: tolerance {rtol:g} not reached in {max_iter} "
                              f"iterations (bounds {lo:.10g}, {hi:.10g})")
        iterations += 1
        gamma = math.sqrt(lo * hi)
        above, s, w = test(gamma)
        if s > lo:
            lo, peak = s, w
        if not above:
            hi = gamma
        hi = max(hi, lo)
    return HinfNorm(0.5 * (lo + hi), lo, hi, peak, iterations, discrete, True)


def hinf_norm(A: npt.ArrayLike, B: npt.ArrayLike, C: npt.ArrayLike,
              D: npt.ArrayLike | None = None, *, discrete: bool = False,
              rtol: float = 1e-6) -> float:
    """H-infinity norm (``inf`` if unstable) to relative tolerance ``rtol``.

    See :func:`hinf_norm_bounds` for the algorithm and the parameters; the value returned is
    within ``rtol / 2`` (relative) of the true norm.
    """
    return hinf_norm_bounds(A, B, C, D, discrete=discrete, rtol=rtol).value


def steady_state_covariance(A: npt.ArrayLike, B: npt.ArrayLike, *,
                            discrete: bool = False) -> FloatArray:
    """Stationary covariance of ``dx = A x dt + B dW`` or ``x(k+1) = A x(k) + B w(k)``.

    Continuous: ``A X + X A^T + B B^T = 0`` (unit-intensity white noise, Wang & Fang (7));
    discrete: ``X = A X A^T + B B^T`` (unit-covariance white noise, Liu et al. (9)).

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, r)
    discrete : bool

    Returns
    -------
    numpy.ndarray, shape (n, n)
        Symmetric ``X``.

    Raises
    ------
    UnstableSystemError
        If ``A`` is not Hurwitz (continuous) or Schur (discrete) stable.
    """
    A_ = matrix("A", A, (None, None), what="a finite square matrix")
    n = A_.shape[0]
    B_ = matrix("B", B, (n, None), labels=("n", "r"))
    eig = np.linalg.eigvals(A_)
    if not _is_stable(eig, discrete):
        kind = "Schur" if discrete else "Hurwitz"
        raise UnstableSystemError(f"A is not {kind} stable: no steady state (eigenvalues "
                                  f"{np.round(eig, 6)})", eig)
    Q = B_ @ B_.T
    X = solve_discrete_lyapunov(A_, Q) if discrete else solve_continuous_lyapunov(A_, -Q)
    return 0.5 * (X + X.T)


# ======================================================================= pole regions
@runtime_checkable
class PoleRegion(Protocol):
    """A region of the complex plane for eigenvalues.

    ``margins(lam)`` is >= 0 inside (> 0 for an open region); ``contains`` tests all of
    ``lam``. ``describe()`` names the region for reports.
    """

    def margins(self, lam: npt.ArrayLike) -> FloatArray: ...

    def contains(self, lam: npt.ArrayLike) -> bool: ...

    def describe(self) -> str: ...


class _Region:
    closed: bool = True

    def margins(self, lam: npt.ArrayLike) -> FloatArray:  # pragma: no cover - abstract
        raise NotImplementedError

    def margin(self, lam: npt.ArrayLike) -> float:
        """Smallest margin over ``lam`` (``inf`` for no eigenvalues)."""
        m = self.margins(lam)
        return float(m.min()) if m.size else math.inf

    def contains(self, lam: npt.ArrayLike) -> bool:
        """All of ``lam`` inside (boundary included iff the region is closed)."""
        m = self.margin(lam)
        return m >= 0.0 if self.closed else m > 0.0


@dataclass(frozen=True)
class Parabola(_Region):
    """Wang & Fang's parabolic region ``P(a, b)``, Fact 1 / (8) (closed).

    ``Im^2(lambda) <= -(2 / b) (Re(lambda) + a)``: vertex at ``-a``, opening to the left,
    ``a > 0``, ``b > 0``. Margin: ``-(2 / b)(Re + a) - Im^2`` (units of ``lambda^2``).

    Note: the proof of Wang & Fang's Theorem 1, (28), actually yields
    ``b |lambda|^2 + 2 Re(lambda) + 2 a < 0``, the open disk :meth:`proof_disk`, which lies
    inside ``P(a, b)``.
    """

    a: float
    b: float
    closed: bool = field(default=True, init=False)

    def __post_init__(self) -> None:
        for name in ("a", "b"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite float, got {v!r}")

    def margins(self, lam: npt.ArrayLike) -> FloatArray:
        z = np.atleast_1d(np.asarray(lam, dtype=np.complex128))
        return -(2.0 / self.b) * (z.real + self.a) - z.imag**2

    def proof_disk(self) -> Disk:
        """The disk ``b |lambda|^2 + 2 Re lambda + 2 a < 0`` that (28) establishes.

        Centre ``-1/b``, radius ``sqrt(1/b^2 - 2 a / b)``; empty (radius 0) if
        ``a b >= 1/2``.
        """
        r2 = 1.0 / self.b**2 - 2.0 * self.a / self.b
        return Disk(-1.0 / self.b, math.sqrt(max(r2, 0.0)))

    def describe(self) -> str:
        return f"parabola P(a={self.a:g}, b={self.b:g}): Im^2 <= -(2/b)(Re + a)"


@dataclass(frozen=True)
class LeftHalfPlane(_Region):
    """Open left half plane ``Re(lambda) < -shift`` (Hurwitz stability for ``shift = 0``)."""

    shift: float = 0.0
    closed: bool = field(default=False, init=False)

    def margins(self, lam: npt.ArrayLike) -> FloatArray:
        z = np.atleast_1d(np.asarray(lam, dtype=np.complex128))
        return -z.real - self.shift

    def describe(self) -> str:
        return "open left half plane" + (f" Re < {-self.shift:g}" if self.shift else "")


@dataclass(frozen=True)
class Disk(_Region):
    """Open disk ``|lambda - center| < radius`` (margin ``radius - |lambda - center|``)."""

    center: complex
    radius: float
    closed: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius) and self.radius >= 0):
            raise ValueError(f"radius must be a non-negative finite float, got {self.radius!r}")
        if not np.isfinite(complex(self.center)):
            raise ValueError(f"center must be finite, got {self.center!r}")

    def margins(self, lam: npt.ArrayLike) -> FloatArray:
        z = np.atleast_1d(np.asarray(lam, dtype=np.complex128))
        return self.radius - np.abs(z - complex(self.center))

    def describe(self) -> str:
        c = complex(self.center)
        cs = f"{c.real:g}" if c.imag == 0 else f"{c:g}"
        return f"{'closed' if self.closed else 'open'} disk |lambda - {cs}| < {self.radius:g}"


def unit_disk() -> Disk:
    """The open unit disk (Schur stability)."""
    return Disk(0.0, 1.0)


def poles_in_region(M: npt.ArrayLike, region: PoleRegion) -> bool:
    """Whether all eigenvalues of the square matrix ``M`` lie in ``region``."""
    M_ = matrix("M", M, (None, None), what="a finite square matrix")
    if M_.shape[0] != M_.shape[1]:
        raise ValueError(f"M must be square, got shape {M_.shape}")
    return region.contains(np.linalg.eigvals(M_))


# ====================================================== filters on uncertain plants
@dataclass(frozen=True, eq=False)
class UncertainPlant:
    """Linear plant with norm-bounded uncertainty (Wang & Fang (1)-(3), Liu et al. (1)-(2)).

    Continuous time (``discrete=False``)::

        x' = (A + M1 F N) x + D1 w,     y = (C + M2 F N) x + D2 w,     z = L x

    with ``w`` zero-mean white noise of unit intensity; discrete time
    (``discrete=True``): ``x(k+1) = (A + M1 F N) x(k) + D1 w(k)``, ``y(k) = (C + M2 F N)
    x(k) + D2 w(k)``, ``w(k)`` of unit covariance. ``F`` is any real ``(i, j)`` matrix with
    ``F^T F <= I``. The same ``w`` drives state and measurement.

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (p, n)
    D1 : array_like, shape (n, r)
    D2 : array_like, shape (p, r)
    M1 : array_like, shape (n, i)
    M2 : array_like, shape (p, i)
    N : array_like, shape (j, n)
    L : array_like, shape (q, n)
        Error output ``L e`` whose H-infinity norm is bounded.
    discrete : bool

    Raises
    ------
    ValueError
        Naming the argument with the wrong shape or non-finite entries.
    """

    A: FloatArray
    C: FloatArray
    D1: FloatArray
    D2: FloatArray
    M1: FloatArray
    M2: FloatArray
    N: FloatArray
    L: FloatArray
    discrete: bool = False

    def __post_init__(self) -> None:
        A = matrix("A", self.A, (None, None), what="a finite square matrix")
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be a finite square matrix with shape (n, n), got shape "
                             f"{A.shape}")
        C = matrix("C", self.C, (None, n), labels=("p", "n"))
        p = C.shape[0]
        D1 = matrix("D1", self.D1, (n, None), labels=("n", "r"))
        r = D1.shape[1]
        D2 = matrix("D2", self.D2, (p, r))
        M1 = matrix("M1", self.M1, (n, None), labels=("n", "i"))
        M2 = matrix("M2", self.M2, (p, M1.shape[1]))
        N = matrix("N", self.N, (None, n), labels=("j", "n"))
        L = matrix("L", self.L, (None, n), labels=("q", "n"))
        for name, arr in (("A", A), ("C", C), ("D1", D1), ("D2", D2), ("M1", M1),
                          ("M2", M2), ("N", N), ("L", L)):
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "discrete", bool(self.discrete))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    @property
    def p(self) -> int:
        """Measurement dimension."""
        return self.C.shape[0]

    @property
    def f_shape(self) -> tuple[int, int]:
        """Shape ``(i, j)`` of the uncertainty ``F``."""
        return self.M1.shape[1], self.N.shape[0]

    def uncertainty(self, F: npt.ArrayLike | None) -> FloatArray:
        """Validate ``F`` (scalar allowed for ``(1, 1)``; ``None`` is 0): ``||F||_2 <= 1``.

        Returns
        -------
        numpy.ndarray, shape (i, j)
        """
        shape = self.f_shape
        if F is None:
            return np.zeros(shape)
        arr = to_float_array("F", F)
        if shape == (1, 1) and arr.size == 1:
            arr = arr.reshape(shape)
        if arr.shape != shape or not np.isfinite(arr).all():
            raise ValueError(f"F must be a finite matrix with shape {shape}, got {np.shape(F)}")
        if arr.size and np.linalg.norm(arr, 2) > 1.0 + 1e-12:
            raise ValueError(f"F must satisfy F^T F <= I (spectral norm <= 1), got norm "
                             f"{np.linalg.norm(arr, 2):.6g}")
        return arr

    def perturbed(self, F: npt.ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
        """``(A + M1 F N, C + M2 F N)``, shapes (n, n) and (p, n)."""
        Fm = self.uncertainty(F)
        return self.A + self.M1 @ Fm @ self.N, self.C + self.M2 @ Fm @ self.N


def _gains(plant: UncertainPlant, G: npt.ArrayLike, K: npt.ArrayLike
           ) -> tuple[FloatArray, FloatArray]:
    n, p = plant.n, plant.p
    return (matrix("G", G, (n, n)), matrix("K", K, (n, p), labels=("n", "p")))


def error_system(plant: UncertainPlant, G: npt.ArrayLike, K: npt.ArrayLike,
                 F: npt.ArrayLike | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Augmented system of plant and filter ``xhat' = G xhat + K y`` in ``x_f = [x; e]``.

    Wang & Fang (5) / Liu et al. (6): ``x_f' = (A_f + M_f F N_f) x_f + D_f w``, ``z = C_f x_f``
    with ``e = x - xhat`` and::

        A_f = [[A, 0], [A - G - K C, G]],  D_f = [D1; D1 - K D2],  M_f = [M1; M1 - K M2],
        N_f = [N, 0],                      C_f = [0, L].

    Parameters
    ----------
    plant : UncertainPlant
    G : array_like, shape (n, n)
    K : array_like, shape (n, p)
    F : array_like, shape (i, j), scalar or None
        Uncertainty (``None``: nominal).

    Returns
    -------
    Af : numpy.ndarray, shape (2n, 2n)
        ``A_f + M_f F N_f``.
    Df : numpy.ndarray, shape (2n, r)
    Cf : numpy.ndarray, shape (q, 2n)
    """
    G_, K_ = _gains(plant, G, K)
    Fm = plant.uncertainty(F)
    n = plant.n
    dA = plant.M1 @ Fm @ plant.N
    dC = plant.M2 @ Fm @ plant.N
    Af = np.zeros((2 * n, 2 * n))
    Af[:n, :n] = plant.A + dA
    Af[n:, :n] = plant.A + dA - G_ - K_ @ (plant.C + dC)
    Af[n:, n:] = G_
    Df = np.vstack([plant.D1, plant.D1 - K_ @ plant.D2])
    Cf = np.hstack([np.zeros((plant.L.shape[0], n)), plant.L])
    return Af, Df, Cf


def error_covariance(plant: UncertainPlant, G: npt.ArrayLike, K: npt.ArrayLike,
                     F: npt.ArrayLike | None = None) -> FloatArray:
    """Steady-state error covariance ``P = lim E[e e^T]`` (Wang & Fang (6)-(7), Liu et al. (8)-(9)).

    Returns
    -------
    numpy.ndarray, shape (n, n)
        The ``e`` block of the stationary covariance of :func:`error_system`.

    Raises
    ------
    UnstableSystemError
        If the augmented system is not stable for this ``F``.
    """
    Af, Df, _ = error_system(plant, G, K, F)
    n = plant.n
    return steady_state_covariance(Af, Df, discrete=plant.discrete)[n:, n:].copy()


def uncertainty_samples(f_shape: tuple[int, int], *, n_grid: int = 21, n_directions: int = 4,
                        seed: int = 0) -> list[tuple[str, FloatArray]]:
    """Admissible uncertainties ``F`` (``||F||_2 <= 1``) to evaluate a filter at.

    Scalar ``F`` (shape (1, 1)): the vertices ``-1, +1`` and ``n_grid`` points of
    ``linspace(-1, 1)``. Matrix ``F``: the vertices are the sign matrices ``diag(+-1)``
    (padded with zeros, at most 64), the grid is ``t V`` for ``t`` in ``linspace(-1, 1,
    n_grid)`` along ``n_directions`` directions ``V`` of unit spectral norm (the first is
    ``diag(1)``, the others seeded random products of orthonormal factors).

    Returns
    -------
    list of (kind, F)
        ``kind`` is ``"vertex"`` or ``"grid"``; ``F`` has shape ``f_shape``.
    """
    i, j = (int(s) for s in f_shape)
    if n_grid < 2:
        raise ValueError(f"n_grid must be >= 2, got {n_grid}")
    out: list[tuple[str, FloatArray]] = []
    t = np.linspace(-1.0, 1.0, n_grid)
    if i == 0 or j == 0:
        return [("vertex", np.zeros((i, j)))]
    k = min(i, j)
    if (i, j) == (1, 1):
        out += [("vertex", np.array([[-1.0]])), ("vertex", np.array([[1.0]]))]
        out += [("grid", np.array([[v]])) for v in t]
        return out
    for code in range(min(2**k, 64)):
        V = np.zeros((i, j))
        V[range(k), range(k)] = [1.0 if (code >> b) & 1 else -1.0 for b in range(k)]
        out.append(("vertex", V))
    rng = np.random.default_rng(seed)
    dirs = [np.eye(i, j)]
    for _ in range(max(n_directions - 1, 0)):
        U, _r = np.linalg.qr(rng.standard_normal((i, i)))
        W, _r = np.linalg.qr(rng.standard_normal((j, j)))
        dirs.append(U @ np.eye(i, j) @ W)
    for V in dirs:
        out += [("grid", v * V) for v in t]
    return out


def _f_json(F: FloatArray) -> float | list[list[float]]:
    return float(F[0, 0]) if F.shape == (1, 1) else F.tolist()


@dataclass(frozen=True)
class RobustAnalysis:
    """Pole region, H-infinity norm and error variances of a filter over admissible ``F``.

    Attributes
    ----------
    F : list of numpy.ndarray, shape (i, j) each
        The evaluated uncertainties, in the order of :func:`uncertainty_samples`.
    kinds : list of str
        ``"vertex"`` or ``"grid"`` per sample.
    stable : numpy.ndarray of bool, shape (S,)
        Augmented system stable.
    pole_margin : numpy.ndarray, shape (S,)
        Region margin of the poles of the augmented system ``A_f + M_f F N_f`` (>= 0 inside
        a closed region, > 0 inside an open one).
    hinf : numpy.ndarray, shape (S,)
        ``||C_f (sI - A_f - dA_f)^-1 D_f||_inf`` (``inf`` if unstable).
    covariances : numpy.ndarray, shape (S, n, n)
        Steady-state error covariances (``inf`` if unstable).
    region : PoleRegion
    gamma, sigma2 : float or None, numpy.ndarray (n,) or None
        Requirements, when given.
    """

    F: list[FloatArray]
    kinds: list[str]
    stable: npt.NDArray[np.bool_]
    pole_margin: FloatArray
    hinf: FloatArray
    covariances: FloatArray
    region: PoleRegion
    gamma: float | None = None
    sigma2: FloatArray | None = None

    @property
    def variances(self) -> FloatArray:
        """Diagonals of :attr:`covariances`, shape (S, n)."""
        return np.diagonal(self.covariances, axis1=1, axis2=2).copy()

    @property
    def all_stable(self) -> bool:
        return bool(self.stable.all())

    @property
    def poles_in_region(self) -> bool:
        """Poles inside the region for every evaluated ``F``."""
        closed = getattr(self.region, "closed", True)
        m = float(self.pole_margin.min())
        return m >= 0.0 if closed else m > 0.0

    @property
    def hinf_worst(self) -> float:
        return float(self.hinf.max())

    @property
    def hinf_worst_F(self) -> FloatArray:
        return self.F[int(np.argmax(self.hinf))]

    @property
    def variance_worst(self) -> FloatArray:
        """Largest steady-state variance of each error component over ``F``, shape (n,)."""
        return self.variances.max(axis=0)

    @property
    def variance_worst_F(self) -> list[FloatArray]:
        return [self.F[int(k)] for k in np.argmax(self.variances, axis=0)]

    @property
    def pole_margin_worst(self) -> float:
        return float(self.pole_margin.min())

    @property
    def pole_worst_F(self) -> FloatArray:
        return self.F[int(np.argmin(self.pole_margin))]

    def meets(self) -> dict[str, bool | None]:
        """Each requirement met for all evaluated ``F`` (``None`` if not given)."""
        return {
            "poles_in_region": self.poles_in_region,
            "hinf": None if self.gamma is None else bool(self.hinf_worst <= self.gamma),
            "variance": (None if self.sigma2 is None
                         else bool(np.all(self.variance_worst <= self.sigma2))),
        }

    def to_dict(self) -> dict[str, object]:
        """JSON-safe summary (non-finite numbers become ``None``)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "region": self.region.describe(),
            "n_samples": len(self.F),
            "all_stable": self.all_stable,
            "poles_in_region": self.poles_in_region,
            "pole_margin_worst": num(self.pole_margin_worst),
            "hinf_worst": num(self.hinf_worst),
            "variance_worst": [num(v) for v in self.variance_worst],
            "worst_F": {"hinf": _f_json(self.hinf_worst_F),
                        "variance": [_f_json(F) for F in self.variance_worst_F],
                        "poles": _f_json(self.pole_worst_F)},
            "gamma": self.gamma,
            "sigma2": None if self.sigma2 is None else self.sigma2.tolist(),
            "meets": self.meets(),
        }


def robust_filter_analysis(plant: UncertainPlant, G: npt.ArrayLike, K: npt.ArrayLike, *,
                           region: PoleRegion | None = None, gamma: float | None = None,
                           sigma2: npt.ArrayLike | None = None,
                           samples: Sequence[tuple[str, npt.ArrayLike]] | None = None,
                           n_grid: int = 21, rtol: float = 1e-6) -> RobustAnalysis:
    """Evaluate a filter ``(G, K)`` at the vertices and on a grid of admissible ``F``.

    For each ``F``: poles of ``A_f + M_f F N_f`` against ``region``, the H-infinity norm
    from ``w`` to ``L e`` (:func:`hinf_norm`) and the steady-state error covariance
    (:func:`error_covariance`).

    Parameters
    ----------
    plant : UncertainPlant
    G : array_like, shape (n, n)
    K : array_like, shape (n, p)
    region : PoleRegion, optional
        Default: :class:`LeftHalfPlane` (continuous) or :func:`unit_disk` (discrete).
    gamma : float, optional
        H-infinity requirement, recorded for :meth:`RobustAnalysis.meets`.
    sigma2 : array_like, shape (n,), optional
        Variance bounds ``sigma_i^2``.
    samples : sequence of (kind, F), optional
        Default: :func:`uncertainty_samples` of ``plant.f_shape`` with ``n_grid``.
    n_grid : int
    rtol : float
        Relative tolerance of the H-infinity norms.

    Returns
    -------
    RobustAnalysis
    """
    G_, K_ = _gains(plant, G, K)
    if region is None:
        region = unit_disk() if plant.discrete else LeftHalfPlane()
    s2 = None
    if sigma2 is not None:
        s2 = real_array(sigma2, "sigma2", finite=False).reshape(-1)
        if s2.shape != (plant.n,) or not np.isfinite(s2).all():
            raise ValueError(f"sigma2 must be a finite array of shape ({plant.n},), got "
                             f"{np.shape(sigma2)}")
    samp = list(samples) if samples is not None else uncertainty_samples(plant.f_shape,
                                                                          n_grid=n_grid)
    n = plant.n
    Fs, kinds, stable, margin, hinf, covs = [], [], [], [], [], []
    for kind, F in samp:
        Fm = plant.uncertainty(F)
        Af, Df, Cf = error_system(plant, G_, K_, Fm)
        lam = np.linalg.eigvals(Af)
        ok = _is_stable(lam, plant.discrete)
        Fs.append(Fm)
        kinds.append(str(kind))
        stable.append(ok)
        margin.append(float(region.margins(lam).min()))
        if ok:
            hinf.append(hinf_norm(Af, Df, Cf, discrete=plant.discrete, rtol=rtol))
            covs.append(steady_state_covariance(Af, Df, discrete=plant.discrete)[n:, n:])
        else:
            hinf.append(math.inf)
            covs.append(np.full((n, n), math.inf))
    return RobustAnalysis(F=Fs, kinds=kinds, stable=np.array(stable), pole_margin=np.array(margin),
                          hinf=np.array(hinf), covariances=np.array(covs), region=region,
                          gamma=None if gamma is None else float(gamma), sigma2=s2)
