"""A simulated rig paced to the wall clock, behind a hardware-style API.

Like a real-time target driving a Quanser rig (a HIL board sampled at a fixed rate), a
background thread produces one sensor sample every control period ``dt_s / factor`` of wall
time, whether or not the user's loop keeps up::

    with RealTimeRig("helicopter", profile="hardware") as hw:
        while hw.clock() < 10.0:
            sample = hw.read()                 # waits for the next sample (SI + raw counts)
            hw.write(controller(sample.y))     # voltages for the next period

Timing rules (what a real-time target counts):

- at each sampling instant the thread applies the latest written command (held from the
  period before when nothing new arrived), steps the rig by one control period and
  publishes the new sample;
- a write answers the sample the caller read last; it is **late** (an *overrun*) when that
  sample is no longer the newest, i.e. the next sampling instant passed while the caller
  computed: the command then acts one period (or more) late, as on hardware;
- samples the caller never read are counted as *missed*;
- the simulation itself can fall behind its schedule when the machine is too slow for the
  real-time factor: *sim_overruns* (the schedule is absolute, so it catches up).

Runs are not reproducible bitwise (the timing of the caller's writes matters), like runs on
hardware; with a caller that always keeps up they equal the simulator's.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from testbed.sensors import Quantize, Sensor, Suite

#: Sleep granularity: the thread sleeps until this close to a deadline, then yields.
_SPIN_S = 2e-4


@dataclass(frozen=True)
class RealTimeSample:
    """One sensor sample of the paced rig.

    Attributes
    ----------
    k : int
        Sample index (0 at start).
    t_s : float
        Simulated time of the sample, s.
    y : ndarray, shape (m,)
        Measurements in SI units (the sensor suite's channels).
    counts : dict of str to int
        Raw counts of the quantized channels (encoders: ``round(angle / (2 pi / counts))``).
    wall_s : float
        Wall-clock time the sample was published, s since start.
    truth : dict of ndarray
        The simulator's info (true state, applied action...) for metrics; hardware has none.
    """

    k: int
    t_s: float
    y: np.ndarray
    counts: dict[str, int]
    wall_s: float
    truth: dict[str, np.ndarray] = field(repr=False)


@dataclass
class PacingStats:
    """Timing of a paced run.

    Attributes
    ----------
    steps : int
        Control periods simulated.
    wall_s : float
        Wall-clock time from start to the last sample.
    sim_s : float
        Simulated time ``steps * dt_s``.
    target_wall_s : float
        Wall time the schedule gives the last sample: ``sim_s / realtime_factor``.
    overruns : int
        Late writes (the caller's computation crossed a sampling instant).
    missed_samples : int
        Samples published that the caller never read.
    sim_overruns : int
        Periods the simulation finished more than one period after its deadline.
    max_lateness_s : float
        Largest delay of a publication after its deadline, s.
    """

    steps: int = 0
    wall_s: float = 0.0
    sim_s: float = 0.0
    target_wall_s: float = 0.0
    overruns: int = 0
    missed_samples: int = 0
    sim_overruns: int = 0
    max_lateness_s: float = 0.0

    @property
    def pacing_error(self) -> float:
        """``wall_s / target_wall_s - 1`` (NaN before the first step)."""
        return self.wall_s / self.target_wall_s - 1.0 if self.target_wall_s else float("nan")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, with ``pacing_error``."""
        return {"steps": self.steps, "wall_s": self.wall_s, "sim_s": self.sim_s,
                "target_wall_s": self.target_wall_s, "pacing_error": self.pacing_error,
                "overruns": self.overruns, "missed_samples": self.missed_samples,
                "sim_overruns": self.sim_overruns, "max_lateness_s": self.max_lateness_s}


def _count_channels(sensors: Sensor) -> list[tuple[str, int, float]]:
    """``(name, channel index, step)`` of channels whose outermost decorator quantizes."""
    out, offset = [], 0
    parts = sensors.sensors if isinstance(sensors, Suite) else (sensors,)
    for part in parts:
        if isinstance(part, Quantize):
            out += [(name, offset + i, float(part.step[i])) for i, name in enumerate(part.names)]
        offset += part.dim
    return out


class RealTimeRig:
    """A rig simulated in real time by a background thread, with read/write/clock.

    Parameters
    ----------
    rig : str or Rig subclass
    realtime_factor : float
        Simulated seconds per wall-clock second (1: real time; 2: twice as fast).
    seed : int
        Seed of the episode.
    options : dict, optional
        Reset options (``x0``...).
    sim : testbed.sim.simulator.Simulator, optional
        An existing single-member simulator (e.g. a runner experiment's); otherwise one is
        built from ``rig`` and ``kwargs`` (the environment arguments: ``profile``,
        ``sensors``...).
    """

    def __init__(self, rig: Any = "helicopter", *, realtime_factor: float = 1.0,
                 seed: int = 0, options: dict | None = None, sim: Any = None, **kwargs: Any):
        if not (isinstance(realtime_factor, int | float) and np.isfinite(realtime_factor)
                and realtime_factor > 0):
            raise ValueError(f"realtime_factor must be a positive number, got "
                             f"{realtime_factor!r}")
        if sim is None:
            from testbed.sim import build_simulator

            sim = build_simulator(rig, 1, num_threads=1, **kwargs)
        elif kwargs:
            raise ValueError(f"environment arguments {sorted(kwargs)} given with a simulator")
        if sim.num != 1:
            raise ValueError(f"a real-time rig runs one member, the simulator has {sim.num}")
        self.sim = sim
        self.dt_s = sim.dt_s
        self.factor = float(realtime_factor)
        self.period_wall_s = self.dt_s / self.factor
        self._seed, self._options = int(seed), options
        self._counted = _count_channels(sim.sensors)
        self._lock = threading.Condition()
        self._command = np.zeros(sim.rig.n_actions)
        self._sample: RealTimeSample | None = None
        self._last_read = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._t0 = 0.0
        self.stats = PacingStats()
        self.names = tuple(sim.sensors.names)
        self.units = tuple(sim.sensors.units)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> RealTimeSample:
        """Reset the rig, publish sample 0 and start the sampling thread."""
        if self._thread is not None:
            raise RuntimeError("the real-time rig is already running")
        self.sim.reset(None, [self._seed], self._options)
        self._t0 = time.perf_counter()
        self.stats = PacingStats()
        first = self._publish(0, 0.0)
        with self._lock:
            self._sample = first
            self._last_read = 0  # the caller receives sample 0 from start()
        self._thread = threading.Thread(target=self._run, name="testbed-realtime", daemon=True)
        self._thread.start()
        return first

    def stop(self) -> PacingStats:
        """Stop the sampling thread; the timing statistics of the run."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            raise RuntimeError(f"the simulation thread failed: {self._error}") from self._error
        return self.stats

    def close(self) -> None:
        """Stop and release the simulator."""
        self.stop()
        self.sim.close()

    def __enter__(self) -> RealTimeRig:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ hardware API
    def clock(self) -> float:
        """Simulated time now, s (wall time since start times the real-time factor)."""
        return (time.perf_counter() - self._t0) * self.factor

    def read(self, wait: bool = True, timeout_s: float | None = None) -> RealTimeSample:
        """The latest sample; with ``wait``, block until one newer than the last read.

        Raises
        ------
        TimeoutError
            No new sample within ``timeout_s`` (default: 10 periods).
        RuntimeError
            The rig is not running or its thread failed.
        """
        if self._thread is None:
            raise RuntimeError("start() the real-time rig before reading")
        limit = 10 * self.period_wall_s + 1.0 if timeout_s is None else timeout_s
        with self._lock:
            if wait and not self._lock.wait_for(
                    lambda: self._sample.k > self._last_read or self._error is not None
                    or self._stop.is_set(), timeout=limit):
                raise TimeoutError(f"no sample within {limit:.3f} s")
            if self._error is not None:
                raise RuntimeError(f"the simulation thread failed: {self._error}")
            sample = self._sample
            if sample.k > self._last_read + 1 and self._last_read >= 0:
                self.stats.missed_samples += sample.k - self._last_read - 1
            self._last_read = max(self._last_read, sample.k)
        return sample

    def write(self, action: Any) -> bool:
        """Command for the next period (volts for the helicopter), answering the last read.

        Before :meth:`start`: the command of the first period (default zero).

        Returns
        -------
        bool
            True when on time; False when late (counted in ``stats.overruns``): the next
            sampling instant passed since the sample this answers was read.
        """
        u = self.sim.check_actions(np.asarray(action, float)[None], 1)[0]
        with self._lock:
            if self._thread is None:  # before start(): the command of the first period
                self._command = u
                return True
            on_time = self._sample.k == self._last_read
            if not on_time:
                self.stats.overruns += 1
            self._command = u
        return on_time

    # ------------------------------------------------------------------ the sampling thread
    def _publish(self, k: int, lateness_s: float) -> RealTimeSample:
        sim = self.sim
        y = sim.obs[0].copy()
        counts = {name: int(np.round(y[i] / step)) for name, i, step in self._counted}
        truth = {key: value[0].copy() for key, value in sim.info.items()}
        wall = time.perf_counter() - self._t0
        self.stats.max_lateness_s = max(self.stats.max_lateness_s, lateness_s)
        return RealTimeSample(k=k, t_s=float(sim.info["t"][0]), y=y, counts=counts,
                              wall_s=wall, truth=truth)

    def _run(self) -> None:
        try:
            k = 0
            while not self._stop.is_set():
                deadline = self._t0 + (k + 1) * self.period_wall_s
                self._sleep_until(deadline)
                if self._stop.is_set():
                    break
                with self._lock:
                    command = self._command.copy()
                self.sim.step(command[None])
                k += 1
                lateness = time.perf_counter() - deadline
                if lateness > self.period_wall_s:
                    self.stats.sim_overruns += 1
                with self._lock:
                    self._sample = self._publish(k, max(lateness, 0.0))
                    self.stats.steps = k
                    self.stats.sim_s = k * self.dt_s
                    self.stats.wall_s = self._sample.wall_s
                    self.stats.target_wall_s = k * self.period_wall_s
                    self._lock.notify_all()
                if self.sim.terminated[0]:
                    break
        except BaseException as err:  # reported by read()/stop()
            self._error = err
            with self._lock:
                self._lock.notify_all()

    def _sleep_until(self, deadline: float) -> None:
        while not self._stop.is_set():
            left = deadline - time.perf_counter()
            if left <= 0:
                return
            time.sleep(left - _SPIN_S if left > 2 * _SPIN_S else 0)


def run_scenario(scenario: Any, realtime_factor: float = 1.0) -> dict[str, Any]:
    """One closed-loop episode of a scenario paced to the wall clock.

    The estimator and the controller run in the caller's thread on the samples of a
    :class:`RealTimeRig`: each sample read is estimated and answered with a command.
    Samples missed while they computed are lost to the estimator (it predicts one period
    per sample it sees), late commands act late.

    Returns
    -------
    dict
        The run's summary (``rmse``, ``measurement_rmse``, ``nees_mean``...), ``units``,
        ``meta`` and ``pacing`` (:meth:`PacingStats.as_dict`).
    """
    from threadpoolctl import threadpool_limits

    from testbed.experiment import runner

    experiment = runner.build(scenario, 1, num_threads=1)
    loop = experiment.loop
    sim, stage, controller = loop.sim, loop.stage, loop.controller
    n_steps = int(round(scenario.duration_s / sim.dt_s))
    rt = RealTimeRig(sim=sim, realtime_factor=realtime_factor, seed=scenario.seed)
    x0_hat, P0 = stage.priors(1, [None])
    try:
        with threadpool_limits(1):
            sample = rt.start()
            controller.reset(1)
            x_hat = stage.reset(sample.y[None], sample.truth["state"][None], x0_hat, P0)
            rt.write(controller(x_hat, 0.0)[0])
            while sample.k < n_steps and not sim.terminated[0]:
                sample = rt.read()
                truth = sample.truth
                x_hat = stage.step(sample.y[None], truth["action_applied"][None],
                                   truth["state"][None], truth["disturbance"][None])
                rt.write(controller(x_hat, sample.t_s)[0])
    finally:
        try:
            stats = rt.stop()
        finally:
            experiment.close()
    summary = stage.metrics.summary(0)
    summary.update(units=experiment.meta["units"], meta=experiment.meta, pacing=stats.as_dict(),
                   realtime_factor=float(realtime_factor))
    return summary
