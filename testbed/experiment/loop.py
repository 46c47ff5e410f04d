"""The closed loop, batch-first: simulator -> estimator -> controller -> metrics.

:class:`EstimatorStage` is the estimator in the loop (input transform, channel handling,
priming, metrics), used by both :class:`ClosedLoop` (the runner's ``run``, ``mc``, ``sweep``
and reproductions) and the Gymnasium wrapper :class:`testbed.envs.wrappers.FilterInLoop`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from filters import all_finite, real_array
from filters.base import Primed
from filters.errors import FilterError, FiniteEscapeError
from testbed.estimators import optional
from testbed.experiment.metrics import EpisodeMetrics
from testbed.plugins import PLUGIN_FAILURES, EstimatorFailed, describe
from testbed.sim.simulator import Simulator


class Stopped(RuntimeError):
    """:meth:`ClosedLoop.run` saw its ``stop`` event set (another part of the study failed
    or was interrupted); the batch's results are incomplete."""


class EstimatorContractError(ValueError):
    """An estimator's ``x`` or ``P`` breaks the contract (shape, symmetry, finiteness, PSD)."""


#: Relative tolerance of the covariance checks (symmetry and smallest eigenvalue).
COVARIANCE_TOLERANCE = 1e-8


def check_estimate(name: str, x: Any, P: Any, n: int, when: str) -> None:
    """Raise :class:`EstimatorContractError` (one line) unless ``x`` is (n,) or (N, n) and
    ``P`` (when not None) is (n, n) or (N, n, n), finite, symmetric and PSD to a tolerance.

    Parameters
    ----------
    name : str
        The estimator, for the message.
    x, P : array_like
    n : int
        The design's state dimension.
    when : str
        ``"after the factory"`` or ``"after the first step"``.
    """
    x = np.asarray(x)
    if x.ndim not in (1, 2) or x.shape[-1] != n:
        raise EstimatorContractError(f"filter {name!r}: x must have shape ({n},) (or (N, {n}) "
                                     f"batched) {when}, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise EstimatorContractError(f"filter {name!r}: x is not finite {when}")
    if P is None:
        return
    P = np.asarray(P)
    if P.ndim not in (2, 3) or P.shape[-2:] != (n, n):
        raise EstimatorContractError(f"filter {name!r}: P must have shape ({n}, {n}) (or "
                                     f"(N, {n}, {n}) batched) {when}, got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise EstimatorContractError(f"filter {name!r}: P ({n}, {n}) is not finite {when}")
    scale = max(1.0, float(np.max(np.abs(P))))
    if np.max(np.abs(P - np.swapaxes(P, -1, -2))) > COVARIANCE_TOLERANCE * scale:
        raise EstimatorContractError(f"filter {name!r}: P ({n}, {n}) is not symmetric {when}")
    low = float(np.min(np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, -1, -2)))))
    if low < -COVARIANCE_TOLERANCE * scale:
        raise EstimatorContractError(f"filter {name!r}: P ({n}, {n}) is not positive "
                                     f"semidefinite {when} (smallest eigenvalue {low:.3g})")


class EstimatorStage:
    """One (batched) estimator fed by the simulator's measurements and applied inputs.

    Parameters
    ----------
    estimator : estimator with ``batched = True`` semantics (x (N, n))
    input_transform : callable ``(u (N, nu), x_hat (N, n)) -> (N, nu)``, optional
    metrics : EpisodeMetrics
    prior : (x0 (n,), P0 (n, n) or None)
        Default prior of every member.
    channels : ndarray of int, optional
        Channels of the sensor vector the estimator receives (default: all). The runner
        gives ``design.measurement_index`` (what ``design.discrete``'s ``H`` describes)
        unless the estimator asks for others (its ``channels`` attribute).
    physical_index : ndarray of int, optional
        The rig's physical states in the estimator's state (default: all): the metrics,
        the recording and the controller see ``x[..., physical_index]`` and
        ``P[..., physical_index, physical_index]``.
    name : str
        The estimator's name in error messages.
    """

    def __init__(self, estimator: Any, input_transform: Callable | None,
                 metrics: EpisodeMetrics, prior: tuple[np.ndarray, np.ndarray | None], *,
                 channels: np.ndarray | None = None, physical_index: np.ndarray | None = None,
                 name: str = "estimator"):
        self.estimator = estimator
        self.input_transform = input_transform
        self.metrics = metrics
        self.prior = prior
        self.channels = None if channels is None else np.asarray(channels, dtype=int)
        n = len(prior[0])
        phys = None if physical_index is None else np.asarray(physical_index, dtype=int)
        self.physical_index = None if phys is None or np.array_equal(phys, np.arange(n)) \
            else phys
        # consecutive physical states (the design's first ones): a slice, so that x and P
        # below are views instead of fancy-index copies (the same values)
        self._physical: slice | np.ndarray | None = self.physical_index
        if phys is not None and self.physical_index is not None and len(phys) and \
                np.array_equal(phys, np.arange(phys[0], phys[0] + len(phys))):
            self._physical = slice(int(phys[0]), int(phys[0]) + len(phys))
        self.name = name
        self._checked = False

    def select(self, y: np.ndarray) -> np.ndarray:
        """The channels of ``y`` (..., m) the estimator receives, C-contiguous: numpy's
        batched products (``vecmat``) take another kernel for a strided batch, so a member
        of a batch would differ from the same run alone in the last bit (a view of the
        reset's measurements is strided)."""
        return np.ascontiguousarray(y if self.channels is None
                                    else np.asarray(y)[..., self.channels])

    @property
    def x(self) -> np.ndarray:
        """The estimate of the rig's physical states, (N, n_rig) (possibly a view of the
        estimator's)."""
        x = np.asarray(self.estimator.x)
        return x if self._physical is None else x[..., self._physical]

    @property
    def P(self) -> np.ndarray | None:
        """The marginal covariance of the physical states, (N, n_rig, n_rig), or None
        (possibly a view of the estimator's)."""
        return self._physical_block(self.estimator.P)

    def _physical_block(self, P: Any) -> np.ndarray | None:
        """The physical states' block of a covariance (..., n, n) (None stays None)."""
        i = self._physical
        if P is None or i is None:
            return P
        if isinstance(i, slice):
            return np.asarray(P)[..., i, i]
        return np.asarray(P)[..., i[:, None], i]

    def check(self, when: str) -> None:
        """:func:`check_estimate` of the estimator's full ``x`` and ``P``."""
        check_estimate(self.name, self.estimator.x, self.estimator.P, len(self.prior[0]),
                       when)

    def priors(self, num: int, per: list[dict[str, Any] | None]) -> tuple[np.ndarray, Any]:
        """Priors (N, n) and (n, n) or (N, n, n) from per-member ``estimator`` options."""
        x0, P0 = self.prior
        xs, Ps = [], []
        for prior in per:
            prior = prior or {}
            if not isinstance(prior, dict):
                raise ValueError(f"options['estimator'] must be a dict, got {prior!r}")
            unknown = set(prior) - {"x0", "P0"}
            if unknown:
                raise ValueError(f"unknown options['estimator'] keys {sorted(unknown)}; "
                                 "expected 'x0' and/or 'P0'")
            n = len(x0)
            xs.append(real_array(prior["x0"], "options['estimator']['x0']", (n,))
                      if "x0" in prior else np.asarray(x0, dtype=float))
            Ps.append(None if prior.get("P0") is None else
                      real_array(prior["P0"], "options['estimator']['P0']", (n, n)))
        x = np.array(xs).reshape(num, -1)
        if all(P is None for P in Ps):
            return x, P0
        return x, np.array([P0 if P is None else np.asarray(P, float) for P in Ps])

    def reset(self, y: np.ndarray, x_true: np.ndarray, x0: np.ndarray, P0: Any) -> np.ndarray:
        """Restart from the priors, prime on the first sample, restart the metrics; returns
        the physical estimate."""
        try:
            self.estimator.reset(x0, P0)
            if isinstance(self.estimator, Primed):  # filters that use the first sample
                self.estimator.prime(self.select(y))
        except FilterError:
            raise
        except ValueError as exc:
            if not isinstance(exc, np.linalg.LinAlgError):
                raise  # a bad prior, named by the estimator
            raise EstimatorFailed(f"the estimator's reset raised {describe(exc)} at t = 0 s",
                                  0.0) from exc
        except PLUGIN_FAILURES as exc:
            raise EstimatorFailed(f"the estimator's reset raised {describe(exc)} at t = 0 s",
                                  0.0) from exc
        self.metrics.reset(x_true)
        self._checked = False
        return self.x

    def step(self, y: np.ndarray, u_applied: np.ndarray, x_true: np.ndarray,
             w: np.ndarray | None) -> np.ndarray:
        """One estimator step on ``y`` (N, m) with the applied input; metrics updated;
        returns the physical estimate (N, n_rig)."""
        est = self.estimator
        u = u_applied
        if self.input_transform is not None:
            u = self.input_transform(u, np.asarray(est.x))
        if u is not None:
            u = np.ascontiguousarray(u)
        try:
            x_hat = np.asarray(est.step(self.select(y), u))
        except (FilterError, FloatingPointError):  # typed numerical failures, as they are
            raise
        except PLUGIN_FAILURES as exc:  # LinAlgError, a plug-in's SystemExit...: exit 3, not 2
            time_s = (self.metrics.count + 1) * self.metrics.dt_s
            raise EstimatorFailed(f"the estimator's step raised {describe(exc)} at "
                                  f"t = {time_s:g} s", time_s) from exc
        if not all_finite(x_hat):
            raise FiniteEscapeError("the estimator returned a non-finite estimate",
                                    time=(self.metrics.count + 1) * self.metrics.dt_s, quantity="x",
                                    value=x_hat.copy())
        if not self._checked:
            self.check("after the first step")
            self._checked = True
        x_phys = self.x
        # a covariance the members share (KalmanFilter.shared_P): the metrics factor it once
        shared = optional.shared_covariance(est)
        P = self.P if shared is None else self._physical_block(shared)
        self.metrics.update(x_true, x_phys, P, y, w if w is not None and w.size else None)
        return x_phys


@dataclass
class LoopResult:
    """Outcome of :meth:`ClosedLoop.run` for N members.

    Attributes
    ----------
    seeds : ndarray of int, shape (N,)
    steps : int
    dt_s : float
    metrics : EpisodeMetrics
        Batched: ``metrics.rmse()[state]`` has shape (N,).
    clipped_fraction : ndarray, shape (N,)
    trajectory : dict of ndarray or None
        With ``record``: ``t_s`` (T+1,), ``state``/``estimate`` (N, T+1, n), ``covariance``
        (N, T+1, n, n) or absent, ``measurement`` (N, T+1, m), ``action`` (N, T+1, nu),
        ``setpoint`` (N, T+1, r), and with poses ``body_pos``/``body_quat_wxyz``.
    tape : Tape or None
        With ``run(..., tape=True)``: the simulator's side of the episodes.
    """

    seeds: np.ndarray
    steps: int
    dt_s: float
    metrics: EpisodeMetrics
    clipped_fraction: np.ndarray
    trajectory: dict[str, np.ndarray] | None = None
    tape: Tape | None = None

    def summary(self, index: int) -> dict[str, Any]:
        """Member ``index``'s summary (floats, JSON-ready)."""
        out = self.metrics.summary(index)
        out["clipped_fraction"] = float(self.clipped_fraction[index])
        return out


@dataclass
class Tape:
    """What the simulator fed the estimator stage during one :meth:`ClosedLoop.run`, so that
    another estimator can be run on the same episodes without simulating them again
    (:meth:`ClosedLoop.replay`).

    Valid only while the trajectories do not depend on the estimator: the controller acts on
    the true state (``truth_feedback``) and the simulator is the same (rig, parameters,
    sensors, disturbance, seeds, reset options). Arrays are time-major (row ``k`` is
    contiguous: the estimator receives the same bytes as from the simulator).

    Attributes
    ----------
    seeds : ndarray of int, shape (N,)
    dt_s : float
    measurement : ndarray, shape (T + 1, N, m)
        ``sim.obs`` after the reset (row 0) and after each step.
    state : ndarray, shape (T + 1, N, n)
    action : ndarray, shape (T + 1, N, nu)
        The applied input (row ``k + 1``: over step ``k``).
    setpoint : ndarray, shape (T + 1, N, r)
    disturbance : list of (ndarray or None)
        ``info["disturbance"]`` of each step (T entries).
    clipped_fraction : ndarray, shape (N,)
    taps : list of ndarray, shape (T + 1, N, d)
        The latest values of each :class:`~testbed.sensors.decorators.Tap` of the sensors
        (:func:`sensor_taps` order) after the reset and after each step: a design's input
        transform may read them (the vehicle's measured ``a_y``).
    """

    seeds: np.ndarray
    dt_s: float
    measurement: np.ndarray
    state: np.ndarray
    action: np.ndarray
    setpoint: np.ndarray
    disturbance: list[np.ndarray | None]
    clipped_fraction: np.ndarray
    taps: list[np.ndarray]

    @property
    def steps(self) -> int:
        """Control steps T (fewer than asked when a member terminated the episode)."""
        return len(self.disturbance)


def sensor_taps(sensor: Any) -> list[Any]:
    """The :class:`~testbed.sensors.decorators.Tap` decorators of a sensor tree
    (:class:`~testbed.sensors.Suite` members and decorators' inner sensors, depth first)."""
    from testbed.sensors import Suite
    from testbed.sensors.decorators import Decorator, Tap

    if isinstance(sensor, Suite):
        return [tap for part in sensor.sensors for tap in sensor_taps(part)]
    if isinstance(sensor, Decorator):
        return ([sensor] if isinstance(sensor, Tap) else []) + sensor_taps(sensor.inner)
    return []


#: The per-step arrays of a :class:`Tape`.
_TAPE_ARRAYS = ("measurement", "state", "action", "setpoint")


class ClosedLoop:
    """N episodes of simulator + estimator + controller, stepped together.

    Parameters
    ----------
    sim : Simulator
    stage : EstimatorStage
    controller : object with ``reset(num)`` and ``__call__(x_hat, t_s) -> u``

    Attributes
    ----------
    truth_feedback : bool
        Give the controller the true state instead of the estimate (default False), so that
        the trajectories do not depend on the estimator (``testbed score`` compares
        estimators on identical trajectories this way).
    """

    def __init__(self, sim: Simulator, stage: EstimatorStage, controller: Any):
        self.sim, self.stage, self.controller = sim, stage, controller
        self.truth_feedback = False

    def run(self, seeds: np.ndarray, duration_s: float, options: Any = None, *,
            record: bool | dict[str, np.ndarray] = False, poses: bool = False,
            bar: tqdm | None = None,
            on_step: Callable[[int, dict[str, Any]], None] | None = None,
            stop: threading.Event | None = None,
            tape: bool = False) -> LoopResult:
        """Run ``len(seeds)`` episodes of ``duration_s`` (rounded to control periods).

        Parameters
        ----------
        seeds : array of int, shape (N,)
        duration_s : float
        options : dict or sequence of N dicts, optional
            Reset options of the simulator plus ``estimator`` (``x0``, ``P0``).
        record : bool or dict of ndarray
            Keep the trajectories (or write them into the given arrays).
        poses : bool
            Also record body poses (for the 3D view).
        bar : tqdm, optional
            Advanced by one per step.
        on_step : callable ``(k, row) -> None``, optional
            Observer called after the reset (``k = 0``) and after each step ``k``, with
            ``row`` = :meth:`row` (``t_s`` and the current arrays of all N members, read-only
            views valid during the call: copy what you keep). It only reads; the run is the
            same with or without it.
        stop : threading.Event, optional
            Checked before each step: when set, the run raises :class:`Stopped` (a study
            running batches in several threads stops them all this way).
        tape : bool
            Also keep what the simulator fed the estimator (``LoopResult.tape``), for
            :meth:`replay`.
        """
        sim, stage, ctrl = self.sim, self.stage, self.controller
        n = sim.num
        seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
        if len(seeds) != n:
            raise ValueError(f"got {len(seeds)} seeds for a batch of {n}")
        n_steps = int(round(duration_s / sim.dt_s)) if np.isfinite(duration_s) else 0
        if n_steps < 1:
            raise ValueError(f"duration must cover at least one control period "
                             f"({sim.dt_s} s), got {duration_s}")
        if options is None or isinstance(options, dict):
            shared = dict(options or {})
            priors = [shared.pop("estimator", None)] * n
            per: Any = shared
        else:
            per = [dict(o or {}) for o in options]
            priors = [o.pop("estimator", None) for o in per]
        x0_hat, P0 = stage.priors(n, priors)
        sim.record_poses = poses
        sim.reset(None, [int(s) for s in seeds], per)
        ctrl.reset(n)
        info = sim.info
        x_hat = stage.reset(sim.obs.copy(), info["state"], x0_hat, P0)
        rec = self._recorder(record, n_steps)
        if rec is not None:
            self._record(rec, 0)
        rows = self._tape_rows(n_steps) if tape else None
        if rows is not None:
            self._tape_row(rows, 0)
        if on_step is not None:
            on_step(0, self.row(0.0))
        clipped = np.zeros(n, dtype=np.int64)
        with threadpool_limits(1):
            for k in range(n_steps):
                if stop is not None and stop.is_set():
                    raise Stopped(f"stopped at t = {k * sim.dt_s:g} s")
                sim.step(ctrl(info["state"] if self.truth_feedback else x_hat,
                              k * sim.dt_s))
                x_hat = stage.step(sim.obs, info["action_applied"], info["state"],
                                   info["disturbance"])
                flags = info["action_clipped"]  # (n, nu): one input's column is its any()
                clipped += flags[:, 0] if flags.shape[1] == 1 else flags.any(axis=1)
                if rec is not None:
                    self._record(rec, k + 1)
                if rows is not None:
                    self._tape_row(rows, k + 1)
                if on_step is not None:
                    on_step(k + 1, self.row((k + 1) * sim.dt_s))
                if bar is not None:
                    bar.update()
                if sim.terminated.any():
                    n_steps = k + 1
                    if rec is not None:
                        rec = {key: v[:, :n_steps + 1] for key, v in rec.items()}
                    break
        trajectory = None
        if rec is not None:
            rec["t_s"] = np.arange(n_steps + 1) * sim.dt_s
            trajectory = rec
        kept = None
        if rows is not None:
            kept = Tape(seeds=seeds, dt_s=sim.dt_s,
                        **{key: rows[key][:n_steps + 1] for key in _TAPE_ARRAYS},
                        disturbance=rows["disturbance"][:n_steps],
                        clipped_fraction=clipped / n_steps,
                        taps=[values[:n_steps + 1] for values in rows["taps"]])
        return LoopResult(seeds=seeds, steps=n_steps, dt_s=sim.dt_s, metrics=stage.metrics,
                          clipped_fraction=clipped / n_steps, trajectory=trajectory, tape=kept)

    def _tape_rows(self, n_steps: int) -> dict[str, Any]:
        sim = self.sim
        n, T = sim.num, n_steps + 1
        dims = {"measurement": sim.sensors.dim, "state": sim.rig.n_states,
                "action": sim.rig.n_actions, "setpoint": len(sim.rig.tracked_states)}
        rows: dict[str, Any] = {key: np.zeros((T, n, d)) for key, d in dims.items()}
        rows["disturbance"] = []
        rows["taps"] = [np.zeros((T, n, tap.dim)) for tap in sensor_taps(sim.sensors)]
        return rows

    def _tape_row(self, rows: dict[str, Any], k: int) -> None:
        info = self.sim.info
        rows["measurement"][k] = self.sim.obs
        rows["state"][k] = info["state"]
        rows["action"][k] = info["action_applied"]
        rows["setpoint"][k] = info["setpoint"]
        for values, tap in zip(rows["taps"], sensor_taps(self.sim.sensors), strict=True):
            values[k] = tap.last
        if k > 0:
            w = info["disturbance"]
            rows["disturbance"].append(None if w is None else np.array(w))

    def replay(self, tape: Tape, options: Any = None, *,
               record: bool | dict[str, np.ndarray] = False) -> LoopResult:
        """The estimator stage on the episodes of an earlier :meth:`run` (its ``tape``),
        without simulating them again.

        The estimator receives what it received in that run, step for step (measurements,
        applied inputs, true states for the metrics, disturbances), so the result is the
        one :meth:`run` with the same seeds gives, bitwise, as long as the trajectories do
        not depend on the estimator (the controller acts on the truth, the simulator is the
        same): checking that is the caller's part.

        Parameters
        ----------
        tape : Tape
        options : dict or sequence of N dicts, optional
            As in :meth:`run`; only the ``estimator`` priors are used here.
        record : bool or dict of ndarray
            As in :meth:`run` (no poses).
        """
        stage = self.stage
        n = tape.state.shape[1]
        if n != self.sim.num:
            raise ValueError(f"the tape has {n} members, the loop {self.sim.num}")
        if options is None or isinstance(options, dict):
            priors = [dict(options or {}).get("estimator")] * n
        else:
            priors = [dict(o or {}).get("estimator") for o in options]
        x0_hat, P0 = stage.priors(n, priors)
        n_steps = tape.steps
        taps = sensor_taps(self.sim.sensors)
        if len(taps) != len(tape.taps):
            raise ValueError(f"the tape has {len(tape.taps)} sensor taps, the loop {len(taps)}")

        def restore_taps(k: int) -> None:
            for tap, values in zip(taps, tape.taps, strict=True):
                tap.last[:] = values[k]

        restore_taps(0)
        stage.reset(tape.measurement[0].copy(), tape.state[0], x0_hat, P0)
        self.sim.record_poses = False
        rec = self._recorder(record, n_steps)
        if rec is not None:
            self._replay_record(rec, tape, 0)
        with threadpool_limits(1):
            for k in range(n_steps):
                restore_taps(k + 1)
                stage.step(tape.measurement[k + 1], tape.action[k + 1], tape.state[k + 1],
                           tape.disturbance[k])
                if rec is not None:
                    self._replay_record(rec, tape, k + 1)
        if rec is not None:
            rec["t_s"] = np.arange(n_steps + 1) * tape.dt_s
        return LoopResult(seeds=tape.seeds, steps=n_steps, dt_s=tape.dt_s,
                          metrics=stage.metrics, clipped_fraction=tape.clipped_fraction,
                          trajectory=rec)

    def _replay_record(self, rec: dict[str, np.ndarray], tape: Tape, k: int) -> None:
        rec["state"][:, k] = tape.state[k]
        rec["estimate"][:, k] = self.stage.x
        if "covariance" in rec:
            rec["covariance"][:, k] = self.stage.P
        rec["measurement"][:, k] = tape.measurement[k]
        rec["action"][:, k] = tape.action[k]
        rec["setpoint"][:, k] = tape.setpoint[k]

    def trajectory_shapes(self, n_steps: int, poses: bool = False) -> dict[str, tuple]:
        """Shapes of the recorded arrays for ``n_steps`` steps (without ``t_s``)."""
        sim = self.sim
        n, T = sim.num, n_steps + 1
        nx, m, nu = sim.rig.n_states, sim.sensors.dim, sim.rig.n_actions
        shapes = {"state": (n, T, nx), "estimate": (n, T, nx), "measurement": (n, T, m),
                  "action": (n, T, nu), "setpoint": (n, T, len(sim.rig.tracked_states))}
        if self.stage.estimator.P is not None:  # the physical states' block
            shapes["covariance"] = (n, T, nx, nx)
        if poses:
            nb = sim.physics.nbody
            shapes.update(body_pos=(n, T, nb, 3), body_quat_wxyz=(n, T, nb, 4))
        return shapes

    def _recorder(self, record: Any, n_steps: int) -> dict[str, np.ndarray] | None:
        if record is False or record is None:
            return None
        shapes = self.trajectory_shapes(n_steps, self.sim.record_poses)
        if record is True:
            return {k: np.zeros(s) for k, s in shapes.items()}
        for key, shape in shapes.items():
            if key not in record or record[key].shape != shape:
                raise ValueError(f"record[{key!r}] must have shape {shape}")
        return dict(record)

    def row(self, t_s: float) -> dict[str, Any]:
        """The current values of all members, as :meth:`run` records them.

        Returns
        -------
        dict
            ``t_s`` (float) and views ``state``/``estimate`` (N, n), ``covariance``
            (N, n, n) or None, ``measurement`` (N, m), ``action`` (N, nu), ``setpoint``
            (N, r), and with recorded poses ``body_pos`` (N, nbody, 3) and
            ``body_quat_wxyz`` (N, nbody, 4).
        """
        sim, stage = self.sim, self.stage
        info = sim.info
        row = {"t_s": t_s, "state": info["state"], "estimate": stage.x,
               "covariance": stage.P, "measurement": sim.obs,
               "action": info["action_applied"], "setpoint": info["setpoint"]}
        if sim.record_poses:
            row["body_pos"], row["body_quat_wxyz"] = sim.physics.poses
        return row

    def _record(self, rec: dict[str, np.ndarray], k: int) -> None:
        sim, stage = self.sim, self.stage
        info = sim.info
        rec["state"][:, k] = info["state"]
        rec["estimate"][:, k] = stage.x
        if "covariance" in rec:
            rec["covariance"][:, k] = stage.P
        rec["measurement"][:, k] = sim.obs
        rec["action"][:, k] = info["action_applied"]
        rec["setpoint"][:, k] = info["setpoint"]
        if "body_pos" in rec:
            rec["body_pos"][:, k] = sim.physics.poses[0]
            rec["body_quat_wxyz"][:, k] = sim.physics.poses[1]

    def close(self) -> None:
        """Stop the physics threads."""
        self.sim.close()
