"""The right-hand side of the central H-infinity filters of :mod:`filters.hinf_polynomial` as
one cubic form, for fast RK4 steps on small systems.

Every term of the filter equations (see :mod:`filters.hinf_polynomial`)::

    dx_f/dt = F(x_f, P) + E u + (P C^T + B D^T) W (y - C x_f),       W = (D D^T)^-1
    dP/dt   = A(x_f, P) P + (A(x_f, P) P)^T + B B^T
              - (P C^T + B D^T) W (C P^T + D B^T) + gamma^-2 P L^T L P^T

is a monomial of degree <= 3 in ``z = [1, x_f, vec(P), y, u]`` (``vec``: row-major), for all
three filters (``F`` and ``A`` are cubic in ``x_f`` and ``P``). So the stacked right-hand side
``r = [dx_f; vec(dP)]`` is ``r = R mono(z)``: ``mono(z)`` are the distinct products
``z_a z_b z_c`` (``a <= b <= c``) that occur, and ``R`` (``(n + n^2) x U``) holds their
coefficients. One RK4 stage is then three gathers, two products and one matrix product instead
of some forty small array operations (the batch sits on the last axis: ``z`` is ``(d, N)``).

``R`` is linear in the polynomial coefficients ``a0..a3`` (each term has exactly one of them
or none), so for time-varying coefficients ``R(t) = R0 + sum_c vec(a_c(t)) T_c``, with
``T_c`` computed once from the symmetrized unit tensors. The terms without a coefficient need
``B``, ``C``, ``D``, ``L``, ``E`` constant.

``R`` is built from a dense tensor of ``d^3 (n + n^2)`` entries, ``d = 1 + n + n^2 + m + k``,
so the cubic form is used for small systems only (:data:`MAX_ENTRIES`; ``n = 2`` with one
observation gives 3072), the other filters keep the term-by-term evaluation.
"""

from __future__ import annotations

import numpy as np

from filters._linalg import FloatArray
from filters.polynomial_model import PolynomialModel, symmetrize_tensor

#: Largest ``d^3 (n + n^2)`` for which the cubic form is used.
MAX_ENTRIES = 50_000
#: The filters' drift variants: the polynomial filter (14)-(15) and the linearized filter
#: with ``F = f(m)`` or ``F = a0 + J(m) m``.
VARIANTS = ("poly", "system", "jacobian")


class CubicForm:
    """``r(z) = R(t) mono(z)``: the filter's stacked right-hand side.

    Parameters
    ----------
    model : PolynomialModel
        Needs ``constant_matrices`` (``B, C, D, L, E`` constant).
    variant : {"poly", "system", "jacobian"}
        ``"poly"``: ``F = f_hat`` (14), ``A = A_hat`` (:class:`~filters.hinf_polynomial.
        PolynomialHInfFilter`); ``"system"`` / ``"jacobian"``: ``F = f(m)`` or
        ``a0 + J(m) m`` and ``A = J(m)`` (:class:`~filters.hinf_polynomial.
        LinearizedHInfFilter`).
    gm2 : float
        ``gamma^-2``.
    t0 : float
        Time at which the constant coefficients are read, s.

    Attributes
    ----------
    n, m, k, d : int
        State, observation and input dimensions; length of ``z``.
    ns : int
        ``n + n^2``, the length of ``r``.
    A, B, C : numpy.ndarray of int, shape (U,)
        ``mono(z) = z[A] * z[B] * z[C]``.
    """

    def __init__(self, model: PolynomialModel, variant: str, gm2: float, t0: float) -> None:
        if variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
        if not model.constant_matrices:
            raise ValueError("the cubic form needs constant B, C, D, L and E")
        self._model = model
        n, m, k = model.n, model.m, model.k
        self.n, self.m, self.k = n, m, k
        self.ns = ns = n + n * n
        self.d = d = 1 + ns + m + k
        sel = _selectors(n, m, k)
        c = model.at(t0)
        self._varying = model.varying
        const = {name: None if name in self._varying else getattr(c, name)
                 for name in ("a0", "a1", "a2", "a3")}
        DDt = c.D @ c.D.T
        W = np.linalg.inv(0.5 * (DDt + DDt.T))
        BDt = c.B @ c.D.T
        BBt = c.B @ c.B.T
        gain = _gain_tensor(sel, 0.5 * (BBt + BBt.T), BDt if np.any(BDt) else None,
                            0.5 * (W + W.T), c.C, c.L, c.E, gm2)
        given = {name: a[None] for name, a in const.items() if a is not None}
        M0 = gain.reshape(d**3, ns)
        if given:
            M0 = M0 + _drift_tensor(sel, variant, **given).reshape(d**3, ns)
        # the tensor of each unit entry of the time-varying coefficients (symmetrized)
        blocks = []
        for name in self._varying:
            order = {"a0": 1, "a1": 2, "a2": 3, "a3": 4}[name]
            basis = np.eye(n**order).reshape(n**order, *(n,) * order)
            if order > 2:
                basis = np.array([symmetrize_tensor(e) for e in basis])
            blocks.append(_drift_tensor(sel, variant, **{name: basis}).reshape(-1, d**3, ns))
        T = np.concatenate(blocks) if blocks else np.zeros((0, d**3, ns))

        # the products z_a z_b z_c that occur, each once (a <= b <= c)
        used = np.flatnonzero(np.any(M0 != 0.0, axis=1) | np.any(T != 0.0, axis=(0, 2)))
        abc = np.sort(np.stack(np.unravel_index(used, (d, d, d)), axis=1), axis=1)
        keys, inverse = np.unique(abc[:, 0] * d * d + abc[:, 1] * d + abc[:, 2],
                                  return_inverse=True)
        self.A, self.B, self.C = keys // (d * d), (keys // d) % d, keys % d
        U = keys.size
        R0 = np.zeros((U, ns))
        np.add.at(R0, inverse, M0[used])
        self._R0 = np.ascontiguousarray(R0.T)  # (ns, U)
        self._cache: dict[float, FloatArray] = {}
        self._T: FloatArray | None = None
        if T.shape[0]:
            Tc = np.zeros((T.shape[0], U, ns))
            np.add.at(Tc, (slice(None), inverse), T[:, used])
            self._T = np.ascontiguousarray(Tc.transpose(0, 2, 1).reshape(T.shape[0], ns * U))

    @staticmethod
    def size(model: PolynomialModel) -> int:
        """``d^3 (n + n^2)``: the entries of the dense tensor the form is built from."""
        n = model.n
        d = 1 + n + n * n + model.m + model.k
        return d**3 * (n + n * n)

    def matrix(self, t: float) -> FloatArray:
        """``R(t)``, shape ``(n + n^2, U)`` (cached per time; do not modify)."""
        if self._T is None:
            return self._R0
        R = self._cache.get(t)
        if R is None:
            values = [self._model.coefficient(name, t) for name in self._varying]
            raw = (values[0].ravel() if len(values) == 1  # type: ignore[union-attr]
                   else np.concatenate([v.ravel() for v in values]))  # type: ignore[union-attr]
            R = self._R0 + (raw @ self._T).reshape(self._R0.shape)
            if len(self._cache) > 8:
                self._cache.clear()
            self._cache[t] = R
        return R


def _selectors(n: int, m: int, k: int) -> dict[str, FloatArray]:
    """Unit tensors picking ``1``, ``x_i``, ``P_ij``, ``y_q``, ``u_j`` out of ``z``."""
    ns = n + n * n
    d = 1 + ns + m + k
    e0 = np.zeros(d)
    e0[0] = 1.0
    X = np.zeros((d, n))
    X[1 + np.arange(n), np.arange(n)] = 1.0
    P = np.zeros((d, n, n))
    idx = np.arange(n * n)
    P[1 + n + idx, idx // n, idx % n] = 1.0
    Y = np.zeros((d, m))
    Y[1 + ns + np.arange(m), np.arange(m)] = 1.0
    U = np.zeros((d, k))
    U[1 + ns + m + np.arange(k), np.arange(k)] = 1.0
    return {"e0": e0, "X": X, "P": P, "Y": Y, "U": U}


def _stack(sel: dict[str, FloatArray], Mx: FloatArray, MP: FloatArray) -> FloatArray:
    """``[Mx, vec(MP)]`` along the output axis, shape ``(d, d, d, n + n^2)``."""
    d, n = sel["X"].shape
    return np.concatenate([Mx, MP.reshape(d, d, d, n * n)], axis=-1)


def _drift_tensor(sel: dict[str, FloatArray], variant: str, a0: FloatArray | None = None,
                  a1: FloatArray | None = None, a2: FloatArray | None = None,
                  a3: FloatArray | None = None) -> FloatArray:
    """The terms with a polynomial coefficient, for ``r`` coefficient sets at once.

    Each given coefficient has a leading axis of length ``r`` (symmetrized tensors; the sets
    of different coefficients are summed, so pass one coefficient for a basis).

    Returns
    -------
    numpy.ndarray, shape (r, d, d, d, n + n^2)
        ``F`` and ``A P + (A P)^T`` of each set.
    """
    e0, X, P = sel["e0"], sel["X"], sel["P"]
    d, n = X.shape
    r = next(a.shape[0] for a in (a0, a1, a2, a3) if a is not None)

    def ein(spec: str, *ops: FloatArray) -> FloatArray:
        return np.einsum(spec, *ops, optimize=True)

    Mx = np.zeros((r, d, d, d, n))
    AP = np.zeros((r, d, d, d, n, n))
    poly = variant == "poly"
    if a0 is not None:
        Mx += ein("a,b,c,rk->rabck", e0, e0, e0, a0)
    if a1 is not None:
        Mx += ein("a,b,ci,rki->rabck", e0, e0, X, a1)
        AP += ein("a,b,cjl,rkj->rabckl", e0, e0, P, a1)
    if a2 is not None:
        Mx += (2.0 if variant == "jacobian" else 1.0) * ein("a,bi,cj,rkij->rabck", e0, X, X, a2)
        if poly:
            Mx += ein("a,b,cij,rkij->rabck", e0, e0, P, a2)
        AP += 2.0 * ein("a,bi,cjl,rkij->rabckl", e0, X, P, a2)
    if a3 is not None:
        Mx += (3.0 if variant == "jacobian" else 1.0) * ein("ai,bj,cl,rkijl->rabck", X, X, X,
                                                           a3)
        AP += 3.0 * ein("ai,bj,cml,rkijm->rabckl", X, X, P, a3)
        if poly:
            Mx += 3.0 * ein("a,bi,cjl,rkijl->rabck", e0, X, P, a3)
            AP += 3.0 * ein("a,bij,cml,rkijm->rabckl", e0, P, P, a3)
    AP += AP.swapaxes(-1, -2)
    return np.concatenate([Mx, AP.reshape(r, d, d, d, n * n)], axis=-1)


def _gain_tensor(sel: dict[str, FloatArray], BBt: FloatArray, BDt: FloatArray | None,
                 W: FloatArray, C: FloatArray, L: FloatArray, E: FloatArray | None,
                 gm2: float) -> FloatArray:
    """The terms without a polynomial coefficient, shape ``(d, d, d, n + n^2)``: ``E u``, the
    gain ``(P C^T + B D^T) W (y - C x)``, ``B B^T``, ``-(P C^T + B D^T) W (C P^T + D B^T)``
    and ``gamma^-2 P L^T L P^T``."""
    e0, X, P, Y, U = sel["e0"], sel["X"], sel["P"], sel["Y"], sel["U"]
    d, n = X.shape

    def ein(spec: str, *ops: FloatArray) -> FloatArray:
        return np.einsum(spec, *ops, optimize=True)

    Mx = np.zeros((d, d, d, n))
    MP = np.zeros((d, d, d, n, n))
    CtW = C.T @ W
    G = CtW @ C
    if E is not None and U.shape[1]:
        Mx += ein("a,b,cj,kj->abck", e0, e0, U, E)
    Mx += ein("a,bkj,cq,jq->abck", e0, P, Y, CtW)
    Mx -= ein("a,bkj,ci,ji->abck", e0, P, X, G)
    MP += ein("a,b,c,kl->abckl", e0, e0, e0, BBt)
    MP -= ein("a,bki,clj,ij->abckl", e0, P, P, G)
    if BDt is not None:
        BW = BDt @ W
        H = CtW @ BDt.T
        Mx += ein("a,b,cq,kq->abck", e0, e0, Y, BW)
        Mx -= ein("a,b,ci,ki->abck", e0, e0, X, BW @ C)
        MP -= ein("a,b,cki,il->abckl", e0, e0, P, H)
        MP -= ein("a,b,cli,ik->abckl", e0, e0, P, H)
        MP -= ein("a,b,c,kl->abckl", e0, e0, e0, BW @ BDt.T)
    if gm2:
        MP += gm2 * ein("a,bki,clj,ij->abckl", e0, P, P, L.T @ L)
    return _stack(sel, Mx, MP)
