"""The process model of a matched (augmented) design: the rig's MuJoCo model composed with
the design's extra (actuator), bias and delay states (:class:`AugmentedProcessModel`;
:mod:`testbed.estimators.nonlinear` describes the whole design model).

This module imports no rig module: the designer's rig comes with the design.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from testbed.design import DesignModel
from testbed.estimators.jacobians import differences, period_tangent, perturbed
from testbed.estimators.mujoco_model import (
    FD_EPS,
    MujocoProcessModel,
    PhysicalInput,
    gravity,
)


class AugmentedProcessModel:
    """``f(x, u)`` of a matched (augmented) design: the rig's MuJoCo model composed with the
    design's extra (actuator), bias and delay states.

    State ``x = [p (rig states), e (extra states), rest (biases, delays, input memory)]``
    (:func:`testbed.design.build_matched_design`'s order); ``u`` absolute
    (:class:`AbsoluteInput`).

    - ``e``: the design's continuous ``A_ee``, ``B_e`` (the matched linear design, one
      source of truth), exactly discretized per physics step: ``e_{i+1} = Phi e_i + Gamma
      (u - [o(x_k), 0])``; the physical input of physics step ``i`` is ``w_i = o(x_k) + S_u
      (u - [o(x_k), 0]) + S_e e_i`` (:class:`PhysicalInput`, ``o`` the operating input at the
      period's start). Extra states relative to the operating input (the helicopter's
      ``dact = act - V_g(pitch)``, :attr:`InputStates.relative`) are re-referenced to the
      period's end state: ``e_{k+1} = e_N + R (o(x_k) - o(x_{k+1}))``.
    - ``p``: the nominal MuJoCo model stepped ``frame_skip`` physics steps with the inputs
      ``w_i`` (:meth:`MujocoProcessModel.rollout`; gravity and joint limits in the MJCF, so a
      design input that stands for a stop's reaction is not a MuJoCo input).
    - ``rest``: the rows of ``design.discrete`` (``F``, ``B``), except the first delay state
      of a channel the sensors declare nonlinear (``SensorModel.nonlinear``), which takes the
      channel's nonlinear value
      ``h(p_k, w_0)`` (``w`` of the input memory when the design keeps one).

    Rows of ``x`` that share ``[p, e]`` and ``u`` bitwise are rolled out once (the UKF's
    standard points along the bias and delay states, and its simplex points after the first
    ``d + 1``, keep the mean's ``[p, e]``: ``2 d + 1`` and ``d + 2`` rollouts per member).

    Jacobian ``F(x, u)``: the ``[p, e]`` columns of the ``[p, e]`` rows and of the
    nonlinear delay rows by finite differences (step ``eps``, forward or ``centered``): with
    the process model's ``jacobian="step"`` (default) the rig block by the tangent recursion
    of one-physics-step derivatives through the physical inputs ``w_i([p, e])``
    (:meth:`_jacobian_step`), with ``"rollout"`` over one rollout of every perturbed state of
    every row; the other entries exactly from ``design.discrete.F``.

    Parameters
    ----------
    design : DesignModel
        Augmented (``design.physical_index`` set).
    process : MujocoProcessModel
        The nominal rig's model at ``design.dt_s``.
    """

    #: The constant input-derivative maps (:meth:`_input_maps`; made on first use).
    _maps: dict[str, np.ndarray] | None = None

    def __init__(self, design: DesignModel, process: MujocoProcessModel) -> None:
        rig = process.rig
        self.process, self.rig = process, rig
        self.input = PhysicalInput(rig, design)
        nr, ne = self.input.nr, self.input.ne
        self.nr, self.ne, self.d, self.n = nr, ne, nr + ne, design.n
        self.k = len(design.input_names)
        self.eps, self.centered = process.eps, process.centered
        Ac = np.asarray(design.continuous.A, float)
        Bc = np.asarray(design.continuous.B, float)
        e = slice(nr, nr + ne)
        if np.any(Ac[e, :nr]) or np.any(Ac[e, nr + ne:]):
            raise ValueError("the design's extra states must evolve on their own (A_ee, B_e): "
                             "rows of A couple them to other states")
        h = float(process.model.opt.timestep)
        N = process.frame_skip
        # [Phi Gamma; 0 I] per physics step (exact ZOH), and its powers 0..N
        blk = np.zeros((ne + self.k, ne + self.k))
        blk[:ne, :ne], blk[:ne, ne:] = Ac[e, e], Bc[e]
        step = expm(blk * h)
        powers = [np.eye(ne + self.k)]
        for _ in range(N):
            powers.append(step @ powers[-1])
        stack = np.stack(powers)  # (N + 1, ne + k, ne + k)
        self._Phi = np.ascontiguousarray(stack[:, :ne, :ne])  # (N + 1, ne, ne)
        self._Gam = np.ascontiguousarray(stack[:, :ne, ne:])  # (N + 1, ne, k)
        F = np.asarray(design.discrete.F, float)
        self._F_rest = F[self.d:]
        self._B_rest = np.asarray(design.discrete.B, float)[self.d:]
        self.g = gravity(process.model)
        names = list(design.state_names)
        delays = (design.extras.get("augmentation") or {}).get("delays", {})
        mem = [i for i, nm_ in enumerate(names) if i >= self.d and nm_.endswith("_prev")
               and nm_[:-5] in design.input_names]
        self._memory = np.array(mem, int) if len(mem) == self.k else None
        self._rows = []
        declared = design.sensors.nonlinear
        for ch, d in delays.items():
            if d and ch in declared:
                self._rows.append((names.index(f"{ch}_delay1") - self.d, *declared[ch]))
        self.nonlinear = tuple(ch for ch, d in delays.items() if d and ch in declared)
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _inputs(self, x: np.ndarray, u: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The physical inputs of a period's physics steps from ``x``'s ``[p, e]`` columns.

        Returns
        -------
        W : ndarray, shape (M, N, k_rig), or (M, 1, k_rig) for a plain input (held)
        E_N : ndarray, shape (M, n_e), or None (plain)
            The extra states at the period's end, before re-referencing.
        off : ndarray, shape (M, k_rig), or None (plain)
            The operating input at the period's start.
        """
        nr, inp = self.nr, self.input
        if inp.plain:
            return u[:, None, :inp.kr], None, None
        p, e = x[:, :nr], x[:, nr:self.d]
        off = inp.offset(p)
        rel = np.array(u, float, copy=True)  # inp.relative(p, u), its offset computed once
        rel[:, :inp.kr] -= off
        # e_i, i = 0..N: Phi^i e + Gamma_i rel
        E = np.einsum("iab,mb->mia", self._Phi, e) + np.einsum("iak,mk->mia", self._Gam, rel)
        base = off + rel @ inp.spec.from_input.T  # (M, k_rig)
        W = base[:, None, :] + E[:, :-1] @ inp.spec.from_states.T  # (M, N, k_rig)
        return W, E[:, -1], off

    def _ends(self, p_next: np.ndarray, E_N: np.ndarray, off: np.ndarray) -> np.ndarray:
        """The extra states at the period's end, re-referenced to ``p_next`` (M, n_e)."""
        relative = self.input.spec.relative
        if np.any(relative):
            return E_N + (off - self.input.offset(p_next)) @ relative.T
        return E_N

    def _pe(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ``[p, e]`` part of ``f`` (M, d) and the first physical input ``w_0``."""
        W, E_N, off = self._inputs(x, u)
        p_next = self.process.rollout(x[:, :self.nr], W)
        if E_N is None:
            return p_next, W[:, 0]
        return np.concatenate([p_next, self._ends(p_next, E_N, off)], axis=1), W[:, 0]

    def _pe_unique(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_pe` with each bitwise-distinct ``([p, e], u)`` row rolled out once (the
        UKF's sigma points along the bias and delay states share the mean's)."""
        if len(x) < 2:
            return self._pe(x, u)
        key = np.ascontiguousarray(np.concatenate([x[:, :self.d], u], axis=1))
        rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1])))[:, 0]
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        if len(first) == len(x):
            return self._pe(x, u)
        pe, w0 = self._pe(x[first], u[first])
        return pe[inverse], w0[inverse]

    def _full(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        pe, w0 = self._pe_unique(x, u)
        return np.concatenate([pe, self._rest(x, u, w0)], axis=1)

    def _rest(self, x: np.ndarray, u: np.ndarray, w0: np.ndarray) -> np.ndarray:
        """The bias, delay and memory rows of ``f`` (M, n - d), ``w0`` the first physical
        input of the period (M, k_rig)."""
        rest = x @ self._F_rest.T + u @ self._B_rest.T
        if self._rows:
            p = x[:, :self.nr]
            w = w0
            if self._memory is not None:  # the delayed channel sees the remembered input
                mem = x[:, self._memory]
                w = self.input(p, x[:, self.nr:self.d], mem)
            for row, value, _, _ in self._rows:
                rest[:, row] = value(p, w, self.g)
        return rest

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f(x, u)``, shape (M, n), for ``x`` (M, n) and absolute ``u`` (M, k)."""
        cache = self._cache
        if cache is not None and np.array_equal(cache[0], x) and np.array_equal(cache[1], u):
            return cache[2].copy()
        return self._full(np.asarray(x, float), np.asarray(u, float))

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``F(x, u) = df/dx``, shape (M, n, n); caches ``f(x, u)`` for :meth:`__call__`.

        The ``[p, e]`` block as the process model's :attr:`MujocoProcessModel.method` says
        (``"step"``: :meth:`_jacobian_step`; otherwise finite differences of the whole
        period); the other entries as the class docstring says.
        """
        x, u = np.asarray(x, float), np.asarray(u, float)
        if self.process.method == "step":
            return self._jacobian_step(x, u)
        M, n, d = len(x), self.n, self.d
        pts = perturbed(x[:, :d], self.eps, self.centered)
        P = pts.shape[1]
        X = np.repeat(x[:, None, :], P, axis=1)
        X[:, :, :d] = pts
        values = self._full(X.reshape(M * P, n), np.repeat(u, P, axis=0)).reshape(M, P, n)
        self._cache = (x.copy(), u.copy(), values[:, 0].copy())
        J = np.zeros((M, n, n))
        J[:, d:] = self._F_rest
        J[:, :d, :d] = differences(values[:, :, :d], self.eps, self.centered)
        if self._rows:
            rows = np.array([d + row for row, *_ in self._rows])
            J[:, rows] = 0.0
            J[:, rows, :d] = differences(values[:, :, rows], self.eps, self.centered)
            if self._memory is not None:
                for row in rows:
                    J[:, row, self._memory] = self._memory_gradient(x, u, row - d)
        return J

    def _jacobian_step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` by the tangent recursion of the one-physics-step derivatives
        (:func:`testbed.estimators.jacobians.period_tangent`).

        The inputs are linear in the extra states and in the operating input ``o(p)``
        (:meth:`_inputs`), so their derivatives are the constant maps of
        :meth:`_input_maps` times ``do/dp`` (finite differences of ``o`` alone, no physics);
        the nonlinear delay rows take the sensors' declared gradients in the rig state and
        the input, chained through ``dw_0/d[p, e]``. The rig block: ``1 + n_rig + k_rig``
        single physics steps per row and linearization point.
        """
        M, n, d, nr = len(x), self.n, self.d, self.nr
        W, E_N, off = self._inputs(x, u)
        p = x[:, :nr]
        dW = do_p = None
        if E_N is not None:
            maps = self._input_maps()
            if self.input.offsets:
                q = perturbed(p, self.eps, self.centered)
                o = self.input.offset(q.reshape(-1, nr)).reshape(M, q.shape[1], -1)
                do_p = differences(o, self.eps, self.centered)  # at p (the start)
            dW = np.zeros((M, *maps["W_e"].shape[:2], d))  # (M, N, k_rig, d)
            dW[..., nr:] = maps["W_e"]
            if do_p is not None:
                W_o = maps["W_o"]  # (N, k_rig, k_rig): one product per member
                dW[..., :nr] = (W_o.reshape(-1, W_o.shape[2]) @ do_p).reshape(
                    M, *W_o.shape[:2], nr)
        p_next, T = period_tangent(self.process, p, W, dW, d)
        if E_N is None:
            pe_next, J_pe = p_next, T
        else:
            e_next = self._ends(p_next, E_N, off)
            J_e = np.zeros((M, self.ne, d))
            J_e[..., nr:] = maps["E_e"]
            relative = self.input.spec.relative
            if do_p is not None:
                J_e[..., :nr] = maps["E_o"] @ do_p
                if np.any(relative):  # - R do/dp(p_next) T
                    q = perturbed(p_next, self.eps, self.centered)
                    o = self.input.offset(q.reshape(-1, nr)).reshape(M, q.shape[1], -1)
                    J_e -= relative @ (differences(o, self.eps, self.centered) @ T)
            pe_next = np.concatenate([p_next, e_next], axis=1)
            J_pe = np.concatenate([T, J_e], axis=1)
        rest = self._rest(x, u, W[:, 0])
        self._cache = (x.copy(), u.copy(), np.concatenate([pe_next, rest], axis=1))
        J = np.zeros((M, n, n))
        J[:, :d, :d] = J_pe
        J[:, d:] = self._F_rest
        if self._rows:
            self._delay_rows(J, x, u, W[:, 0], dW, do_p)
        return J

    def _input_maps(self) -> dict[str, np.ndarray]:
        """The constant derivative maps of :meth:`_inputs` (made once).

        ``W_e`` (N, k_rig, n_e) = ``dw_i/de = S_e Phi^i``; ``W_o`` (N, k_rig, k_rig) =
        ``dw_i/do = I - S_u,r - S_e Gamma_i,r``; ``E_e`` = ``Phi^N``; ``E_o`` (n_e, k_rig) =
        ``d(E_N + R o)/do = R - Gamma_N,r`` (``,r``: the columns of the rig's inputs);
        ``m_o`` (k_rig, k_rig) = ``I - S_u,r`` (the input of a remembered input ``u``).
        """
        maps = self._maps
        if maps is None:
            spec, kr, N = self.input.spec, self.input.kr, self.process.frame_skip
            Su_r = np.asarray(spec.from_input, float)[:, :kr]
            Se = np.asarray(spec.from_states, float)
            Gam_r = self._Gam[:, :, :kr]
            maps = self._maps = {
                "W_e": Se @ self._Phi[:N], "W_o": np.eye(kr) - Su_r - Se @ Gam_r[:N],
                "E_e": self._Phi[N], "E_o": np.asarray(spec.relative, float) - Gam_r[N],
                "m_o": np.eye(kr) - Su_r}
        return maps

    def _delay_rows(self, J: np.ndarray, x: np.ndarray, u: np.ndarray, w0: np.ndarray,
                    dW: np.ndarray | None, do_p: np.ndarray | None) -> None:
        """The nonlinear delay rows of ``J`` (in place): ``grad_x + grad_w dw/d[p, e]`` with
        ``w`` the period's first input (or that of the input memory), and their memory
        columns."""
        d, nr = self.d, self.nr
        p = x[:, :nr]
        if self._memory is None:
            w, dw = w0, (None if dW is None else dW[:, 0])
        else:  # w = o(p) + S_u (m - [o(p), 0]) + S_e e of the remembered input m
            w = self.input(p, x[:, nr:d], x[:, self._memory])
            dw = None
            if not self.input.plain:
                maps = self._input_maps()
                dw = np.zeros((len(x), self.input.kr, d))
                dw[..., nr:] = np.asarray(self.input.spec.from_states, float)
                if do_p is not None:
                    dw[..., :nr] = maps["m_o"] @ do_p
        for row, _, grad_x, grad_w in self._rows:
            J[:, d + row] = 0.0
            J[:, d + row, :nr] = grad_x(p, w, self.g)
            if dw is not None:
                J[:, d + row, :d] += np.einsum("mk,mkd->md", grad_w(p, w, self.g), dw)
            if self._memory is not None:
                J[:, d + row, self._memory] = self._memory_gradient(x, u, row)

    def _memory_gradient(self, x: np.ndarray, u: np.ndarray, row: int) -> np.ndarray:
        """d(first delay state)/d(input memory) of a nonlinear delayed channel (M, k)."""
        value = next(v for r, v, _, _ in self._rows if r == row)
        mem = x[:, self._memory]
        pts = perturbed(mem, FD_EPS, True)
        M, P, k = pts.shape
        p = np.repeat(x[:, :self.nr], P, axis=0)
        e = np.repeat(x[:, self.nr:self.d], P, axis=0)
        w = self.input(p, e, pts.reshape(M * P, k))
        vals = value(p, w, self.g).reshape(M, P, 1)
        return differences(vals, FD_EPS, True)[:, 0]
