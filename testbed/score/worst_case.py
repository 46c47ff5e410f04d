"""Adversarial search for the worst energy-bounded disturbance of an estimator in the loop.

The gain of a disturbance ``w`` (held over each control period ``dt``) on the scenario's
disturbance channel is::

    gain(w) = ||dz||_2 / ||w||_2,    ||f||_2^2 = sum_k |f_k|^2 dt,
    dz = L (x_hat - x) with w  -  L (x_hat - x) without w

the output estimation error the disturbance causes: the error of the closed-loop run with
``w`` minus the error of the run with the same seed without it (common random numbers:
measurement noise, process noise and the initial estimation error cancel; for a linear loop
``dz`` is exactly the deterministic error system's response). Every reported gain is such a
measured ratio of two runs of the nonlinear rig; a larger one found later only raises it, so
the result is a lower bound of the worst case, never a certificate.

Every closed-loop run of the search measures **probe sensors**: the scenario's sensors with
the rounding of every :class:`~testbed.sensors.Quantize` decorator removed
(:func:`without_quantization`; noise, bias, delays, holds and the linear model kept, the
estimator unchanged). With quantized sensors a disturbance also moves the truth across
quantization steps, and ``dz`` then contains the change of the quantization error, a term of
the order of the step whatever the disturbance: on the helicopter's encoders it floored every
filter's gain at about 1e-3 rad per unit of ``w`` (Kalman 0.00111, Kalman-Bucy 0.00136,
poly-hinf 0.00146 over the quick suite's 3 s) and ranked nothing. Without quantization
``dz`` is the error system's response to ``w`` (plus the rig's and the estimator's own
nonlinearity).

The search (Tierno, Murray, Doyle & Gregory 1997 style):

1. **The loop's error system, measured.** Impulses ``eps e_j`` on each channel of ``w`` at
   step ``k0 = K / 4`` (past the gains' transient), one batched closed-loop run of ``k0 + K``
   steps on the probe sensors (:meth:`LoopEvaluator.impulse_response`), give the impulse
   response ``t_l`` of ``w -> dz``, so that ``dz_k = sum_i t_(k-i) w_i`` (the linearization
   about run 0 at ``k0``, taken as time-invariant). It contains everything in the loop: the
   controller's reaction to the disturbed truth, the estimator's response to measurements and
   inputs (input transform included), the sensors' delays and holds. (The model-based
   alternative, ``t_l = L (g^x_l - sum_(a+b=l) h_a g^y_b)`` from the rig's open-loop
   linearization and the estimator's Markov parameters, :func:`plant_markov`,
   :func:`estimator_markov`, :func:`error_response`, misses the controller: on the
   helicopter the open-loop yaw integrates ``w`` while the LQR holds it, and its predictions
   were 3 to 4 times the gains the loop has.)
2. **Power iteration with the adjoint.** Subspace iteration on ``T^T T`` (forward: the
   convolution; adjoint: the correlation with ``t^T``, both by FFT) gives the top right
   singular vectors ``v_1..v_p`` over the horizon.
3. **Refinement on the nonlinear rig.** ``+-v_1`` scaled to the energy, then
   ``scipy.optimize.differential_evolution`` (derivative-free, vectorized: one batched
   closed-loop run per generation) over ``w(c) = v_1 + sum_i c_i v_(i+1)``, ``c in
   [-1, 1]^(p-1)``, each candidate scaled to the energy.

Random gain: the largest gain of white Gaussian disturbances of the same energy.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution

from testbed.rigs.disturbances import SampledDisturbance
from testbed.score.error_operator import (  # (re-exported: __all__)
    ErrorOperator,
    ImpulseNorm,
    causal_conv,
    error_response,
    estimator_markov,
    hinf_from_impulse,
    plant_markov,
    realize,
    top_singular,
)

#: The linear error system's names are re-exported from :mod:`testbed.score.error_operator`.
__all__ = [
    "ErrorOperator",
    "ImpulseNorm",
    "LoopEvaluator",
    "RESTARTS",
    "SearchResult",
    "causal_conv",
    "error_response",
    "estimator_markov",
    "hinf_from_impulse",
    "plant_markov",
    "population",
    "realize",
    "scaled",
    "search",
    "top_singular",
    "without_quantization",
]

def _unquantized_class() -> type:
    from testbed.sensors import Quantize
    from testbed.sensors.decorators import Decorator

    class Unquantized(Decorator):
        """A :class:`~testbed.sensors.Quantize` with the rounding removed: the measurement
        passes through, the linear model keeps the quantizer's ``q^2 / 12`` (so the design
        model built from the probe sensors is the original one)."""

        def __init__(self, quantizer: Quantize):
            super().__init__(quantizer.inner)
            self.step = quantizer.step

        linear_model = Quantize.linear_model

    return Unquantized


def without_quantization(sensor: Any) -> tuple[Any, list[str]]:
    """A copy of a sensor suite whose :class:`~testbed.sensors.Quantize` decorators pass the
    measurement through unrounded.

    The tree of :class:`~testbed.sensors.Suite` members and
    :class:`~testbed.sensors.decorators.Decorator` wrappers (the way sensors are composed) is
    copied (deep: no state is shared with the original) and each ``Quantize`` is replaced by
    an ``Unquantized`` decorator around the same inner sensor: no rounding, the same linear
    model (``R`` keeps the quantizer's ``q^2 / 12``, so a design model built from the copy is
    the original's). Every other decorator (noise, bias, delay, hold, tap) stays in its place
    and draws the same noise. A quantizer inside a sensor that is neither a ``Suite`` nor a
    ``Decorator`` (a rig's own composite channel) is not found.

    Returns
    -------
    sensor : Sensor
        The copy (the original object itself when nothing is quantized).
    removed : list of str
        The channels whose quantization was removed, in the suite's order.
    """
    from testbed.sensors import Quantize, Suite
    from testbed.sensors.decorators import Decorator

    unquantized = _unquantized_class()
    removed: list[str] = []

    def strip(s: Any) -> Any:
        if isinstance(s, Suite):
            parts = [strip(p) for p in s.sensors]
            if all(a is b for a, b in zip(parts, s.sensors, strict=True)):
                return s
            return Suite(*parts)
        if isinstance(s, Quantize):
            removed.extend(s.names)
            s.inner = strip(s.inner)
            return unquantized(s)
        if isinstance(s, Decorator):
            inner = strip(s.inner)
            if inner is s.inner:
                return s
            s.inner = inner
            return s
        return s

    stripped = strip(copy.deepcopy(sensor))
    if not removed:
        return sensor, []
    order = {name: i for i, name in enumerate(sensor.names)}
    return stripped, sorted(removed, key=order.get)


# ---------------------------------------------------------------------------- loop side
@dataclass
class SearchResult:
    """Outcome of :func:`search` (gains in the channel's units: output unit per w unit).

    Attributes
    ----------
    worst_case_gain : float
        Largest measured gain of the search's candidates.
    worst_case_w : ndarray, shape (K, s)
        The disturbance attaining it (energy ``energy``).
    random_gain : float
        Largest measured gain of the random disturbances.
    linear_gain : float
        ``sigma_max`` of the linearized error system over the horizon (a prediction, and a
        lower bound of its H-infinity norm).
    evaluations : int
        Closed-loop candidate runs (random ones included).
    iterations : int
        Power iterations.
    energy : float
    horizon_s : float
    notes : list of str
    probe_sensors : str
        Description of the sensors of the probe runs (:meth:`Sensor.describe`).
    quantization_removed : list of str
        Channels measured without their quantization in the probe runs
        (:func:`without_quantization`).
    hinf : ImpulseNorm, optional
        The infinite-horizon H-infinity norm of the measured error system
        (:func:`hinf_from_impulse`).
    restart_gains : list of float
        The best gain of each restart of the refinement (``worst_case_gain`` is their
        maximum; their range is the search's spread).
    """

    worst_case_gain: float
    worst_case_w: np.ndarray
    random_gain: float
    linear_gain: float
    evaluations: int
    iterations: int
    energy: float
    horizon_s: float
    notes: list[str] = field(default_factory=list)
    probe_sensors: str = ""
    quantization_removed: list[str] = field(default_factory=list)
    hinf: ImpulseNorm | None = None
    restart_gains: list[float] = field(default_factory=list)

    def describe(self) -> dict[str, Any]:
        """JSON-ready: the search's settings, its linear prediction (finite horizon) and the
        infinite-horizon norm (the report's ``worst_case_search``)."""
        norm = None if self.hinf is None else self.hinf.describe()
        return {"linear_gain": self.linear_gain, "hinf_norm": norm,
                "restart_gains": list(self.restart_gains), "energy": self.energy,
                "horizon_s": self.horizon_s, "evaluations": self.evaluations,
                "iterations": self.iterations, "probe_sensors": self.probe_sensors,
                "quantization_removed": list(self.quantization_removed),
                "quantization": "removed" if self.quantization_removed else "none"}


class LoopEvaluator:
    """Measured gains of candidate disturbances on a built closed loop (batched).

    Two builds of the same probe loop: ``candidates``, whose member 0 runs without ``w`` (the
    baseline of its batch) and every other member a candidate disturbance, and ``impulse``,
    with ``s + 1`` members (member 0 without ``w``; member ``1 + j`` an impulse on channel
    ``j``). Every member of both has the same seed. Each candidate's ``dz`` is taken against
    the baseline of its own batch, not one run elsewhere: an estimator whose arithmetic
    depends on its batch companions (poly-hinf chooses its integration substeps for the whole
    batch) would otherwise put the difference of two integrations into ``dz`` (on
    ``vehicle-step-steer`` it moved poly-hinf's random gain by a factor 3 under a 1e-9
    change of the energy).

    Parameters
    ----------
    candidates : testbed.experiment.runner.Experiment
        Its simulator's disturbance must be ``disturbance``.
    disturbance : SampledDisturbance
        Values (num, >= K, s), rewritten per batch.
    impulse : testbed.experiment.runner.Experiment
        The same loop with ``s + 1`` members; its simulator's disturbance must be
        ``impulse_disturbance``.
    impulse_disturbance : SampledDisturbance
        Values (s + 1, >= 1, s).
    seed : int
    steps : int
        Horizon K.
    output_matrix : ndarray, shape (q, n)
    """

    def __init__(self, candidates: Any, disturbance: SampledDisturbance, impulse: Any,
                 impulse_disturbance: SampledDisturbance, seed: int, steps: int,
                 output_matrix: np.ndarray):
        self.loop, self.dist = candidates.loop, disturbance
        self.impulse_loop, self.impulse_dist = impulse.loop, impulse_disturbance
        s = disturbance.values.shape[2]
        if self.impulse_loop.sim.num != s + 1 or impulse_disturbance.values.shape[2] != s:
            raise ValueError(f"the impulse loop needs {s + 1} members and {s} channels, got "
                             f"{self.impulse_loop.sim.num} and "
                             f"{impulse_disturbance.values.shape[2]}")
        self.seed, self.K = int(seed), int(steps)
        self.L = np.asarray(output_matrix, float)
        self.num = self.loop.sim.num
        if self.num < 2:
            raise ValueError(f"the candidates' loop needs at least 2 members (a baseline and "
                             f"a candidate), got {self.num}")
        self.dt_s = self.loop.sim.dt_s
        self.evaluations = 0
        #: The baseline's output error, (steps, q) from step 1 (set by the impulse response).
        self._baseline: np.ndarray | None = None

    def _errors(self, loop: Any, steps: int) -> np.ndarray:
        """Output errors ``z`` (members, steps run, q) of one run of ``loop``, from step 1."""
        return self._output_errors(loop.run(np.full(loop.sim.num, self.seed),
                                            steps * self.dt_s, record=True))

    def _output_errors(self, result: Any) -> np.ndarray:
        """Output errors ``z`` (members, steps, q) of a recorded run, from step 1."""
        rec = result.trajectory
        return np.einsum("qn,btn->btq", self.L, rec["estimate"] - rec["state"])[:, 1:]

    def baseline(self) -> np.ndarray:
        """The output error of the run without ``w``, (K, q) (or fewer steps, if the episode
        ended): member 0 of the impulse response's run, run now without impulses if that has
        not run yet."""
        if self._baseline is None or len(self._baseline) < self.K:  # none, or cut short
            self.impulse_dist.values[:] = 0.0
            self._baseline = self._errors(self.impulse_loop, self.K)[0]
        return self._baseline[: self.K]

    def run(self, W: np.ndarray) -> np.ndarray:
        """Gains of the candidates ``W`` (B, K, s), in batches of ``num - 1``: member 0 of
        every batch runs without ``w`` and is that batch's baseline (an estimator whose
        arithmetic depends on its batch companions, such as one integrating with a step
        chosen for the whole batch, then differs from the baseline only by ``w``)."""
        W = np.asarray(W, dtype=float)
        gains = np.empty(len(W))
        size = self.num - 1
        for start in range(0, len(W), size):
            chunk = W[start:start + size]
            self.dist.values[:] = 0.0
            self.dist.values[1:1 + len(chunk), : self.K] = chunk
            z = self._errors(self.loop, self.K)
            z0 = z[0]
            steps = z.shape[1]
            dz = z[1:1 + len(chunk)] - z0
            w_energy = np.sum(chunk[:, :steps] ** 2, axis=(1, 2))
            gains[start:start + len(chunk)] = np.sqrt(np.sum(dz**2, axis=(1, 2))
                                                      / np.maximum(w_energy, 1e-300))
            self.evaluations += len(chunk)
        if not np.all(np.isfinite(gains)):
            raise FloatingPointError("a worst-case candidate gave a non-finite gain")
        return gains

    def impulse_response(self, k0: int, eps: float, *, tapes: dict[str, Any] | None = None,
                         key: str = "") -> np.ndarray:
        """The loop's error system measured: ``t_l`` for ``l = 0..K``, shape (K + 1, q, s).

        One batched closed-loop run of ``k0 + K`` steps of the impulse loop: member 0 without
        ``w`` (the baseline, kept for :meth:`run`), member ``1 + j`` with ``w_(k0) = eps e_j``
        (one step, channel ``j``); ``t_l[:, j] = dz_(k0 + l) / eps`` (the timing of
        :class:`ErrorOperator`). The controller's reaction to the disturbed truth (or
        estimate), the estimator's response to the measurements and to the inputs, the
        sensors' delays and holds are all in it; for a linear loop it is exact, otherwise the
        linearization about the run (``eps`` small) at step ``k0`` (an estimator whose gains
        still move after ``k0`` is taken as time-invariant).

        With ``tapes`` and a loop whose controller acts on the truth, the run is simulated
        once per ``key`` (the caller's: everything the run depends on but the estimator) and
        replayed for every further estimator (:meth:`ClosedLoop.replay`, bitwise the same).
        """
        s = self.impulse_dist.values.shape[2]
        if not 1 <= k0 <= self.K:
            raise ValueError(f"k0 must be in [1, {self.K}], got {k0}")
        self.impulse_dist.values[:] = 0.0
        self.impulse_dist.values[1 + np.arange(s), k0, np.arange(s)] = eps
        loop = self.impulse_loop
        if tapes is not None and loop.truth_feedback and key in tapes:
            z = self._output_errors(loop.replay(tapes[key], record=True))
        else:
            shared = tapes is not None and loop.truth_feedback
            result = loop.run(np.full(loop.sim.num, self.seed), (k0 + self.K) * self.dt_s,
                              record=True, tape=shared)
            if shared:
                tapes[key] = result.tape  # type: ignore[index]
            z = self._output_errors(result)
        self.impulse_dist.values[:] = 0.0
        self._baseline = z[0]
        dz = (z[1:1 + s] - z[0]) / eps  # (s, steps, q), row k - 1 is step k
        t = np.zeros((self.K + 1, self.L.shape[0], s))
        rows = dz[:, k0 - 1:k0 + self.K].transpose(1, 2, 0)  # l = 0..K
        t[: len(rows)] = rows
        if not np.all(np.isfinite(t)):
            raise FloatingPointError("the loop's impulse response is not finite")
        return t


def population(dimensions: int) -> int:
    """Members of the refinement's population for ``dimensions`` coefficients (DE's
    ``popsize`` times the dimensions, at least 5)."""
    return dimensions * max(2, int(np.ceil(5 / dimensions))) if dimensions > 0 else 0


def scaled(w: np.ndarray, energy: float, dt_s: float) -> np.ndarray:
    """``w`` (..., K, s) scaled to ``sum_k |w_k|^2 dt = energy`` (each leading index)."""
    norm = np.sqrt(np.sum(w**2, axis=(-2, -1), keepdims=True) * dt_s)
    return w * np.sqrt(energy) / norm


#: Independent restarts of the refinement (their candidates share each closed-loop batch).
RESTARTS = 3


class _Gather:
    """Candidates of several callers (threads) evaluated as one batch per round.

    Each caller hands its candidates to :meth:`__call__` and waits; when every active caller
    has handed its own, they are evaluated together, in the callers' order (deterministic
    whatever the threads' timing), and each gets its part. :meth:`done` retires a caller.
    """

    def __init__(self, evaluate: Any, parties: int):
        self.evaluate = evaluate
        self.cond = threading.Condition()
        self.active = set(range(parties))
        self.pending: dict[int, np.ndarray] = {}
        self.results: dict[int, np.ndarray] = {}
        self.error: BaseException | None = None
        self.round = 0

    def _flush(self) -> None:
        order = sorted(self.pending)
        sizes = [len(self.pending[i]) for i in order]
        try:
            gains = self.evaluate(np.concatenate([self.pending[i] for i in order]))
        except BaseException as err:  # handed to every waiting caller
            self.error = err
        else:
            for i, part in zip(order, np.split(gains, np.cumsum(sizes)[:-1]), strict=True):
                self.results[i] = part
        self.pending.clear()
        self.round += 1
        self.cond.notify_all()

    def __call__(self, index: int, W: np.ndarray) -> np.ndarray:
        with self.cond:
            if self.error is None:
                self.pending[index] = W
                current = self.round
                if set(self.pending) >= self.active:
                    self._flush()
                while self.round == current and self.error is None:
                    self.cond.wait()
            if self.error is not None:
                raise RuntimeError("a batch of the worst-case refinement failed") \
                    from self.error
            return self.results.pop(index)

    def done(self, index: int) -> None:
        with self.cond:
            self.active.discard(index)
            if self.pending and set(self.pending) >= self.active:
                self._flush()


def search(evaluator: LoopEvaluator, t: np.ndarray, *, energy: float, random_draws: int,
           basis: int, generations: int, rng: np.random.Generator,
           restarts: int = RESTARTS) -> SearchResult:
    """The worst-case search on one closed loop (see the module docstring).

    Parameters
    ----------
    evaluator : LoopEvaluator
        Its candidates' loop should have ``restarts * population(basis - 1) + 1`` members
        (one batch per generation of all restarts).
    t : ndarray, shape (lags, q, s)
        Impulse response of the error system (:meth:`LoopEvaluator.impulse_response`, or
        :func:`error_response` of a model), zero beyond ``lags``.
    energy : float
    random_draws, basis, generations : int
    rng : numpy.random.Generator
        Start of the power iteration, the random disturbances, the refinements' streams
        (:meth:`numpy.random.Generator.spawn`).
    restarts : int
        Independent differential-evolution refinements, run in lockstep (one batched
        closed-loop run per generation for all of them): the result is their maximum, and
        the restarts' best gains (``restart_gains``) show its spread.
    """
    if int(restarts) != restarts or restarts < 1:
        raise ValueError(f"restarts must be a positive integer, got {restarts}")
    K, dt = evaluator.K, evaluator.dt_s
    s = t.shape[2]
    op = ErrorOperator(t, K)
    gains, V, iterations = top_singular(op, basis, rng)
    notes: list[str] = []

    random_w = scaled(rng.standard_normal((random_draws, K, s)), energy, dt)
    v1 = scaled(V[0], energy, dt)
    first = evaluator.run(np.concatenate([v1[None], -v1[None], random_w]))
    random_gain = float(first[2:].max())
    best = int(np.argmax(first[:2]))
    sign = 1.0 if best == 0 else -1.0
    worst, worst_w = float(first[best]), sign * v1
    restart_gains = [worst]

    d = len(V) - 1
    if generations > 0 and d > 0:
        streams = rng.spawn(int(restarts))
        records = [{"gain": worst, "w": worst_w} for _ in streams]
        gather = _Gather(evaluator.run, len(streams))

        def candidates(c: np.ndarray) -> np.ndarray:
            c = np.atleast_2d(c.T).reshape(-1, d)  # (S, d)
            w = sign * (V[0][None] + np.einsum("bd,dks->bks", c, V[1:]))
            return scaled(w, energy, dt)

        def refine(index: int) -> None:
            record = records[index]

            def objective(c: np.ndarray) -> np.ndarray:
                w = candidates(c)
                g = gather(index, w)
                j = int(np.argmax(g))
                if g[j] > record["gain"]:
                    record["gain"], record["w"] = float(g[j]), w[j]
                return -g

            try:
                differential_evolution(objective, [(-1.0, 1.0)] * d, maxiter=generations,
                                       popsize=population(d) // d, x0=np.zeros(d),
                                       vectorized=True, updating="deferred", polish=False,
                                       tol=0.0, rng=streams[index])
            except BaseException as err:  # re-raised by the caller
                record["error"] = err
            finally:
                gather.done(index)

        threads = [threading.Thread(target=refine, args=(i,), daemon=True)
                   for i in range(len(streams))]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        for record in records:
            if "error" in record:
                error = record["error"]
                raise error.__cause__ if isinstance(error, RuntimeError) and \
                    error.__cause__ is not None else error
        restart_gains = [r["gain"] for r in records]
        top = int(np.argmax(restart_gains))
        worst, worst_w = records[top]["gain"], records[top]["w"]
    if worst < random_gain:
        notes.append(f"the search ({worst:.2g}) stayed below a random disturbance "
                     f"({random_gain:.2g})")
    return SearchResult(worst_case_gain=worst, worst_case_w=worst_w, random_gain=random_gain,
                        linear_gain=float(gains[0]), evaluations=evaluator.evaluations,
                        iterations=iterations, energy=energy, horizon_s=K * dt, notes=notes,
                        hinf=hinf_from_impulse(t, dt), restart_gains=restart_gains)
