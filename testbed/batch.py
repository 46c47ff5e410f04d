"""Batched closed-loop Monte Carlo: N helicopter episodes with the estimator in the loop.

One batch step advances every trajectory by one control period:

1. the controller, vectorized (:class:`BatchLQRTracker`), on the ``(N, 4)`` estimates;
2. the physics, sensors and disturbances of N environments
   (:class:`~testbed.envs.helicopter_vector.HelicopterBatch`: MuJoCo in a thread pool);
3. the estimator **once** on the whole batch (the filters' leading batch axis);
4. the streaming metrics (:class:`~testbed.metrics.EpisodeMetrics` with a batch axis).

Everything is built by :func:`~testbed.experiment.build_helicopter` (the filter design, the
LQR gain, the sensor suite, the disturbance, the metrics' weights), so trajectory ``i`` equals
``run_episode(build_helicopter(...), duration_s, seed=seeds[i])``: the environment part
bitwise, the estimator to rounding (the batched Kalman filter evaluates the Joseph form as an
explicit product where the single one uses a Cholesky Gram matrix, ~1e-16 relative).

Per-run seeds
-------------
Run ``i`` of ``monte_carlo(seed=s, runs=R)`` uses ``run_seeds(s, R)[i]``, the ``i``-th word of
``numpy.random.SeedSequence(s).generate_state(R)`` (uint32): independent of ``batch_size``,
prefix-stable (the first 10 of 1000 runs are the runs of ``runs=10``), and without the overlap
``s + i`` would give between ``seed=0`` and ``seed=1``. That run equals the single environment
reset with that seed.
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import functools
import shutil
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from testbed.control import LQRTracker
from testbed.envs.helicopter_vector import HelicopterBatch
from testbed.experiment import build_helicopter
from testbed.io import atomic_path
from testbed.metrics import EpisodeMetrics
from testbed.rigs.helicopter import HelicopterParams, gravity_voltage

#: Default number of trajectories stepped together by :func:`monte_carlo`.
DEFAULT_BATCH_SIZE = 1000

_OPENBLAS_THREAD_CONTROLS = (
    ("openblas_get_num_threads", "openblas_set_num_threads"),
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
)


def _openblas_thread_controls() -> list[tuple[Callable[[], int], Callable[[int], None]]]:
    """(get, set) thread-count functions of every OpenBLAS loaded in this process (Linux)."""
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps
                            if "openblas" in line.lower() and ".so" in line})
    except OSError:
        return []
    controls = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get, set_ in _OPENBLAS_THREAD_CONTROLS:
            if hasattr(lib, get) and hasattr(lib, set_):
                controls.append((getattr(lib, get), getattr(lib, set_)))
                break
    return controls


@contextlib.contextmanager
def limit_blas_threads(num: int = 1) -> Iterator[None]:
    """Run the block with OpenBLAS (numpy's and scipy's) limited to ``num`` threads.

    OpenBLAS threads busy-wait after each threaded call; on a small machine they take the
    cores the MuJoCo workers need (measured on 2 cores: batch physics at 40k instead of 60k
    trajectory-steps/s). The batch's linear algebra is on tiny matrices and gains nothing
    from BLAS threads. A no-op where the OpenBLAS libraries cannot be found.
    """
    controls = _openblas_thread_controls()
    saved = [get() for get, _ in controls]
    for _, set_ in controls:
        set_(int(num))
    try:
        yield
    finally:
        for (_, set_), previous in zip(controls, saved, strict=True):
            set_(previous)


def run_seeds(seed: int, runs: int) -> np.ndarray:
    """Per-run environment seeds of ``monte_carlo(seed=seed, runs=runs)``.

    Returns
    -------
    ndarray of int64, shape (runs,)
        ``numpy.random.SeedSequence(seed).generate_state(runs)`` (uint32 words).
    """
    return np.random.SeedSequence(seed).generate_state(runs).astype(np.int64)


class BatchLQRTracker:
    """:class:`~testbed.control.LQRTracker` applied to a batch of estimates.

    Same gain, anti-windup and clock as ``tracker``; one pair of integrators per member. Row
    ``i`` of the output equals what ``tracker`` returns for row ``i`` of the input, bitwise
    (``numpy.matvec`` reproduces ``K @ z``).

    Parameters
    ----------
    tracker : LQRTracker
        Supplies ``K``, ``dt_s``, ``integral`` and ``voltage_limit_v``.
    feedforward : callable ``pitch (N,) -> (N, 2)`` volts
        Gravity compensation (vectorized).
    setpoint : callable ``t_s -> (N, 2) or (2,)`` rad
        Reference of every member.
    """

    def __init__(self, tracker: LQRTracker, feedforward: Callable[[np.ndarray], np.ndarray],
                 setpoint: Callable[[float], np.ndarray]):
        self.K = tracker.K
        self.dt_s = tracker.dt_s
        self.integral = tracker.integral
        self.voltage_limit_v = tracker.voltage_limit_v
        self._feedforward = feedforward
        self._setpoint = setpoint
        self.reset(1)

    def reset(self, num: int) -> None:
        """Clear the integrators of ``num`` members and the clock."""
        self._xi = np.zeros((num, 2))
        self._k = 0

    def __call__(self, x_hat: np.ndarray) -> np.ndarray:
        """Voltages (N, 2) for the estimates ``x_hat`` (N, 4), within the saturation limits."""
        t_s = self._k * self.dt_s
        num = len(x_hat)
        ref = np.broadcast_to(self._setpoint(t_s), (num, 2))
        err = x_hat - np.concatenate([ref, np.zeros((num, 2))], axis=1)
        z = np.concatenate([err, self._xi], axis=1) if self.integral else err
        u = self._feedforward(x_hat[:, 0]) - np.matvec(self.K, z)
        u_sat = np.clip(u, -self.voltage_limit_v, self.voltage_limit_v)
        if self.integral:
            free = np.all(u_sat == u, axis=1)
            self._xi = np.where(free[:, None], self._xi + self.dt_s * err[:, :2], self._xi)
        self._k += 1
        return u_sat


class _ConstantPolicy:
    """The open-loop policy of :func:`build_helicopter` for a batch."""

    def __init__(self, action: np.ndarray):
        self.action = np.asarray(action, dtype=float)

    def reset(self, num: int) -> None:
        """Nothing to clear."""

    def __call__(self, x_hat: np.ndarray) -> np.ndarray:
        return np.broadcast_to(self.action, (len(x_hat), len(self.action)))


@dataclass
class BatchResult:
    """Outcome of :meth:`BatchClosedLoop.run`.

    Attributes
    ----------
    seeds : ndarray of int, shape (N,)
    steps : int
        Control steps per trajectory.
    dt_s : float
        Control period.
    metrics : EpisodeMetrics
        Batched metrics: ``metrics.rmse()[state]`` has shape (N,), etc.
    clipped_fraction : ndarray, shape (N,)
        Fraction of steps with a saturated voltage.
    trajectory : dict of ndarray or None
        With ``record``: ``t_s`` (T+1,), ``state`` and ``estimate`` (N, T+1, 4),
        ``covariance`` (N, T+1, 4, 4), ``measurement`` (N, T+1, m), ``action`` (applied
        voltages) and ``setpoint`` (N, T+1, 2); row 0 is the reset.
    """

    seeds: np.ndarray
    steps: int
    dt_s: float
    metrics: EpisodeMetrics
    clipped_fraction: np.ndarray
    trajectory: dict[str, np.ndarray] | None = None

    def summary(self, index: int) -> dict[str, Any]:
        """Member ``index``'s summary, in the form :func:`run_episode` returns."""
        out = self.metrics.summary(index)
        out["clipped_fraction"] = float(self.clipped_fraction[index])
        return out


class BatchClosedLoop:
    """:func:`~testbed.experiment.build_helicopter`'s closed loop for N trajectories at once.

    Parameters
    ----------
    filter_name, controller : str
        As for :func:`build_helicopter`.
    num_envs : int
        Trajectories per batch.
    num_threads : int, optional
        Physics threads (default: the CPUs available).
    **build_kwargs
        Further arguments of :func:`build_helicopter` (``sensors``, ``disturbance``,
        ``process_noise_scale``, ``params``...).

    Notes
    -----
    The single experiment is built once and supplies every piece: its estimator is copied and
    reset with a batch of priors, its LQR gain is vectorized, its environment is the template
    of the :class:`HelicopterBatch`, its metrics' weights are reused. The estimator's input is
    the applied voltage minus the gravity voltage at the estimated pitch with nominal
    parameters, as in ``build_helicopter``.
    """

    def __init__(self, filter_name: str = "kalman", controller: str = "lqr", *,
                 num_envs: int = 1, num_threads: int | None = None, **build_kwargs: Any):
        experiment = build_helicopter(filter_name, controller, **build_kwargs)
        wrapper = experiment.env
        inner = wrapper.unwrapped
        self.meta = dict(experiment.meta)
        self.sim = HelicopterBatch(inner, num_envs, num_threads=num_threads)
        self.num_envs = self.sim.num_envs
        self.dt_s = float(inner.dt_s)
        self.state_names = list(inner.state_names)
        self.measurement_names = list(inner.sensors.names)
        self.estimator = copy.deepcopy(wrapper.estimator)
        self._prior = (np.array(self.estimator.x), np.array(self.estimator.P))
        self._filter_index = wrapper.measurement_index  # channels the estimator reads
        self._reference_metrics = wrapper.metrics()
        self._gravity = functools.partial(gravity_voltage, HelicopterParams())
        if isinstance(experiment.policy, LQRTracker):
            self.controller: BatchLQRTracker | _ConstantPolicy = BatchLQRTracker(
                experiment.policy, self._gravity, self.sim.setpoints_at)
        else:
            self.controller = _ConstantPolicy(experiment.policy(self._prior[0]))

    def _new_metrics(self) -> EpisodeMetrics:
        ref = self._reference_metrics
        return EpisodeMetrics(ref.state_names, ref.dt_s, ref.measured_state_index,
                              ref.output_matrix, ref.ratio_weight)

    def _priors(self, priors: list[dict[str, Any] | None]) -> tuple[np.ndarray, np.ndarray]:
        """Estimator priors (N, n) and (n, n) or (N, n, n) from per-member ``estimator`` options."""
        x0, P0 = self._prior
        xs, Ps = [], []
        for prior in priors:
            prior = prior or {}
            unknown = set(prior) - {"x0", "P0"}
            if unknown:
                raise ValueError(f"unknown options['estimator'] keys {sorted(unknown)}; "
                                 "expected 'x0' and/or 'P0'")
            xs.append(np.asarray(prior.get("x0", x0), dtype=float))
            Ps.append(prior.get("P0"))
        if all(P is None for P in Ps):
            return np.array(xs), P0
        return np.array(xs), np.array([P0 if P is None else np.asarray(P, float) for P in Ps])

    def run(self, seeds: Sequence[int], duration_s: float,
            options: dict[str, Any] | Sequence[dict[str, Any] | None] | None = None, *,
            record: bool | dict[str, np.ndarray] = False, progress: bool = False,
            bar: tqdm | None = None) -> BatchResult:
        """Run N closed-loop episodes.

        Parameters
        ----------
        seeds : sequence of int, length N
            Environment seed of each trajectory.
        duration_s : float
            Simulated time; rounded to whole control periods.
        options : dict or sequence of N dicts, optional
            Reset options as for :func:`run_episode` (``x0``, ``params``, ``setpoints``,
            ``estimator``); one dict applies to every member.
        record : bool or dict of ndarray
            Keep full trajectories (see :class:`BatchResult`), or write them into the given
            arrays (same keys and shapes, e.g. memory maps).
        progress : bool
            Show a tqdm bar over the steps (ignored when ``bar`` is given).
        bar : tqdm, optional
            Bar to advance by one per step.

        Returns
        -------
        BatchResult
        """
        n = self.num_envs
        seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
        if len(seeds) != n:
            raise ValueError(f"got {len(seeds)} seeds for a batch of {n}")
        if not (np.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be a positive finite time in s, got {duration_s}")
        n_steps = int(round(duration_s / self.dt_s))
        if options is None or isinstance(options, dict):
            shared = dict(options or {})
            priors = [shared.pop("estimator", None)] * n
            per = self.sim.member_options(shared, n)
        else:
            per = [dict(o or {}) for o in options]
            priors = [o.pop("estimator", None) for o in per]
        x0_hat, P0 = self._priors(priors)
        sim, est, ctrl = self.sim, self.estimator, self.controller
        ctrl.reset(n)
        sim.reset(None, seeds.tolist(), per)
        est.reset(x0_hat, P0)
        metrics = self._new_metrics()
        metrics.reset(sim.info["state"])
        rec = self._recorder(record, n_steps)
        if rec is not None:
            self._record(rec, 0)
        clipped = np.zeros(n, dtype=np.int64)
        index = self._filter_index
        info = sim.info
        own_bar = bar is None
        if own_bar:
            bar = tqdm(total=n_steps, desc="batch", unit="step", disable=not progress,
                       leave=False)
        try:
            with limit_blas_threads(1):
                x_hat = est.x
                for k in range(n_steps):
                    sim.step(ctrl(x_hat))
                    u_model = info["action_applied"] - self._gravity(x_hat[:, 0])
                    y = sim.obs
                    x_hat = est.step(y if index is None else y[:, index], u_model)
                    metrics.update(info["state"], x_hat, est.P, y, info["disturbance"])
                    clipped += info["action_clipped"].any(axis=1)
                    if rec is not None:
                        self._record(rec, k + 1)
                    bar.update()
        finally:
            if own_bar:
                bar.close()
        trajectory = None
        if rec is not None:
            rec["t_s"] = np.arange(n_steps + 1) * self.dt_s
            trajectory = rec
        return BatchResult(seeds=seeds, steps=n_steps, dt_s=self.dt_s, metrics=metrics,
                           clipped_fraction=clipped / max(n_steps, 1), trajectory=trajectory)

    def trajectory_shapes(self, n_steps: int) -> dict[str, tuple[int, ...]]:
        """Shapes of the recorded arrays for ``n_steps`` steps (without ``t_s``)."""
        n, T = self.num_envs, n_steps + 1
        nx, m = len(self.state_names), len(self.measurement_names)
        return {"state": (n, T, nx), "estimate": (n, T, nx), "covariance": (n, T, nx, nx),
                "measurement": (n, T, m), "action": (n, T, 2), "setpoint": (n, T, 2)}

    def _recorder(self, record: bool | dict[str, np.ndarray],
                  n_steps: int) -> dict[str, np.ndarray] | None:
        if record is False or record is None:
            return None
        shapes = self.trajectory_shapes(n_steps)
        if record is True:
            return {k: np.zeros(s) for k, s in shapes.items()}
        for key, shape in shapes.items():
            if key not in record or record[key].shape != shape:
                raise ValueError(f"record[{key!r}] must have shape {shape}")
        return dict(record)

    def _record(self, rec: dict[str, np.ndarray], k: int) -> None:
        info = self.sim.info
        rec["state"][:, k] = info["state"]
        rec["estimate"][:, k] = self.estimator.x
        rec["covariance"][:, k] = self.estimator.P
        rec["measurement"][:, k] = self.sim.obs
        rec["action"][:, k] = info["action_applied"]
        rec["setpoint"][:, k] = info["setpoint"]

    def close(self) -> None:
        """Stop the physics threads."""
        self.sim.close()


def run_batch(filter_name: str = "kalman", controller: str = "lqr", *, seeds: Sequence[int],
              duration_s: float, options: dict | Sequence[dict | None] | None = None,
              record: bool = False, progress: bool = False, num_threads: int | None = None,
              **build_kwargs: Any) -> BatchResult:
    """Run ``len(seeds)`` closed-loop episodes as one batch (see :class:`BatchClosedLoop`).

    Trajectory ``i`` equals ``run_episode(build_helicopter(filter_name, controller,
    **build_kwargs), duration_s, seed=seeds[i], options=options[i])``.
    """
    loop = BatchClosedLoop(filter_name, controller, num_envs=len(seeds),
                           num_threads=num_threads, **build_kwargs)
    try:
        return loop.run(seeds, duration_s, options, record=record, progress=progress)
    finally:
        loop.close()


class _NpzStream:
    """Trajectories written batch by batch into ``.npy`` memory maps, zipped into one ``.npz``.

    RAM stays bounded by one batch; the ``.npz`` (stored, uncompressed: ``numpy.load`` reads
    it like ``numpy.savez``'s) appears atomically (:func:`testbed.io.atomic_path`).
    """

    def __init__(self, path: str | Path, shapes: dict[str, tuple[int, ...]]):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._dir = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        self.arrays = {k: np.lib.format.open_memmap(self._dir / f"{k}.npy", mode="w+",
                                                    dtype=np.float64, shape=s)
                       for k, s in shapes.items()}

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Views of runs ``start:stop`` of every array."""
        return {k: a[start:stop] for k, a in self.arrays.items()}

    def finish(self, extra: dict[str, np.ndarray]) -> Path:
        """Write the ``.npz`` with the trajectories and the ``extra`` arrays."""
        try:
            for array in self.arrays.values():
                array.flush()
            names = list(self.arrays)
            self.arrays.clear()
            with atomic_path(self.path) as tmp, zipfile.ZipFile(
                    tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                for key in names:
                    zf.write(self._dir / f"{key}.npy", arcname=f"{key}.npy")
                for key, value in extra.items():
                    with zf.open(f"{key}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)
        finally:
            self.abort()
        return self.path

    def abort(self) -> None:
        """Remove the temporary files."""
        self.arrays.clear()
        shutil.rmtree(self._dir, ignore_errors=True)


def _stats(values: np.ndarray) -> dict[str, float]:
    q05, q95 = np.quantile(values, [0.05, 0.95])
    return {"mean": float(np.mean(values)), "q05": float(q05), "q95": float(q95)}


def monte_carlo(filter_name: str = "kalman", runs: int = 1000, duration_s: float = 80.0,
                seed: int = 0, batch_size: int | None = None, progress: bool = True,
                save_npz: str | Path | None = None, *, num_threads: int | None = None,
                **build_kwargs: Any) -> dict[str, Any]:
    """Monte-Carlo study of an estimator in the helicopter's closed loop.

    Parameters
    ----------
    filter_name : {"kalman", "kalman-bucy"}
    runs : int
        Number of trajectories.
    duration_s : float
        Simulated time per trajectory (rounded to control periods).
    seed : int
        Base seed; run ``i`` uses ``run_seeds(seed, runs)[i]`` (see the module docstring).
    batch_size : int, optional
        Trajectories stepped together (default ``min(runs, DEFAULT_BATCH_SIZE)``); results do
        not depend on it.
    progress : bool
        tqdm bar over the steps of all batches.
    save_npz : path, optional
        Also write every trajectory (``state``, ``estimate``, ``covariance``,
        ``measurement``, ``action``, ``setpoint`` of shape ``(runs, steps + 1, ...)``, plus
        ``t_s``, ``seeds`` and the per-run metrics) to this ``.npz``, atomically. Costs
        ``runs * (steps + 1) * 8 * (28 + m)`` bytes on disk, one batch of it in RAM.
    num_threads : int, optional
        Physics threads.
    **build_kwargs
        Arguments of :func:`build_helicopter` (``controller``, ``sensors``, ``disturbance``,
        ``process_noise_scale``, ``params``...).

    Returns
    -------
    dict
        JSON-ready: ``runs``, ``steps_per_run``, ``wall_s``, ``traj_steps_per_s``,
        ``rmse`` ``{state: {"mean", "q05", "q95"}}`` (over runs), ``measurement_rmse``
        (same form), ``nees_mean`` (mean over runs of each run's mean NEES, None without
        covariance), ``T_final`` ``{"mean", "q05", "q95"}`` when a deterministic disturbance
        is present (else None), ``clipped_fraction_mean``, the seeds' derivation and the
        experiment's ``meta``.
    """
    if int(runs) != runs or runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs}")
    if batch_size is not None and (int(batch_size) != batch_size or batch_size < 1):
        raise ValueError(f"batch_size must be a positive integer, got {batch_size}")
    runs = int(runs)
    batch_size = min(runs, int(batch_size or DEFAULT_BATCH_SIZE))
    start_time = time.perf_counter()
    seeds = run_seeds(seed, runs)
    starts = list(range(0, runs, batch_size))
    loops: dict[int, BatchClosedLoop] = {}

    def loop_for(size: int) -> BatchClosedLoop:
        if size not in loops:
            loops[size] = BatchClosedLoop(filter_name, num_envs=size, num_threads=num_threads,
                                          **build_kwargs)
        return loops[size]

    first = loop_for(batch_size)
    n_steps = int(round(duration_s / first.dt_s)) if np.isfinite(duration_s) else 0
    if n_steps < 1:
        raise ValueError(f"duration_s must cover at least one control period, got {duration_s}")
    stream = None
    if save_npz is not None:
        shapes = {k: (runs, *s[1:]) for k, s in first.trajectory_shapes(n_steps).items()}
        stream = _NpzStream(save_npz, shapes)
    per_run: dict[str, list[np.ndarray]] = {"nees": [], "T": [], "clipped": []}
    rmse: dict[str, list[np.ndarray]] = {k: [] for k in first.state_names}
    meas: dict[str, list[np.ndarray]] = {}
    bar = tqdm(total=len(starts) * n_steps, desc=f"monte carlo ({filter_name})", unit="step",
               disable=not progress)
    try:
        with bar:
            for start in starts:
                size = min(batch_size, runs - start)
                loop = loop_for(size)
                record = stream.rows(start, start + size) if stream is not None else False
                result = loop.run(seeds[start:start + size], duration_s, record=record, bar=bar)
                for k, v in result.metrics.rmse().items():
                    rmse[k].append(v)
                for k, v in result.metrics.measurement_rmse().items():
                    meas.setdefault(k, []).append(v)
                per_run["nees"].append(result.metrics.nees_mean())
                per_run["T"].append(result.metrics.noise_output_ratio())
                per_run["clipped"].append(result.clipped_fraction)
    except BaseException:
        if stream is not None:
            stream.abort()
        raise
    finally:
        for loop in loops.values():
            loop.close()
    rmse_all = {k: np.concatenate(v) for k, v in rmse.items()}
    meas_all = {k: np.concatenate(v) for k, v in meas.items()}
    nees = None if per_run["nees"][0] is None else np.concatenate(per_run["nees"])
    T = None if per_run["T"][0] is None else np.concatenate(per_run["T"])
    clipped = np.concatenate(per_run["clipped"])
    if stream is not None:
        extra: dict[str, np.ndarray] = {
            "t_s": np.arange(n_steps + 1) * first.dt_s, "seeds": seeds,
            "state_names": np.array(first.state_names),
            "measurement_names": np.array(first.measurement_names),
            "rmse": np.stack([rmse_all[k] for k in first.state_names], axis=1),
            "clipped_fraction": clipped}
        if nees is not None:
            extra["nees_mean"] = nees
        if T is not None:
            extra["T_final"] = T
        stream.finish(extra)
    wall_s = time.perf_counter() - start_time
    return {
        "filter": filter_name,
        "runs": runs,
        "duration_s": n_steps * first.dt_s,
        "steps_per_run": n_steps,
        "seed": seed,
        "seeds": "numpy.random.SeedSequence(seed).generate_state(runs)",
        "batch_size": batch_size,
        "threads": first.sim.physics.num_threads,
        "wall_s": wall_s,
        "traj_steps_per_s": runs * n_steps / wall_s,
        "rmse": {k: _stats(v) for k, v in rmse_all.items()},
        "measurement_rmse": {k: _stats(v) for k, v in meas_all.items()},
        "nees_mean": None if nees is None else float(np.mean(nees)),
        "nees": None if nees is None else _stats(nees),
        "T_final": None if T is None else _stats(T),
        "clipped_fraction_mean": float(np.mean(clipped)),
        "npz": None if save_npz is None else str(save_npz),
        "meta": first.meta,
    }
