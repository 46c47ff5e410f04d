"""Simulated units: recordings of a rig with hidden parameters, made by the simulator.

What the tests and the benchmark identify: the rig at parameter scales the identification
is not told, driven by a given input sequence, recorded through its sensor suite (with the
suite's noise, quantization, biases and delays) like a real unit's log.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from testbed.identify.simulate import PHYSICS_DT_MAX_S, build_rig
from testbed.io.recording import Recording
from testbed.rigs.base import Rig
from testbed.sim.simulator import Simulator


def random_steps(rng: np.random.Generator, n_samples: int, dt_s: float, low: np.ndarray,
                 high: np.ndarray, hold_s: tuple[float, float] = (0.2, 1.0),
                 still_s: float = 0.0, rest: np.ndarray | None = None) -> np.ndarray:
    """A multi-level random step input: each input channel holds a uniform level in
    ``[low, high]`` for a random time in ``hold_s``; the first ``still_s`` at ``rest``.

    Returns
    -------
    ndarray, shape (n_samples, nu)
    """
    low, high = np.atleast_1d(np.asarray(low, float)), np.atleast_1d(np.asarray(high, float))
    u = np.empty((n_samples, len(low)))
    for c in range(len(low)):
        k = 0
        while k < n_samples:
            hold = max(1, int(rng.uniform(*hold_s) / dt_s))
            u[k:k + hold, c] = rng.uniform(low[c], high[c])
            k += hold
    still = int(round(still_s / dt_s))
    if still:
        u[:still] = 0.0 if rest is None else rest
    return u


def simulated_recording(rig_cls: type[Rig], inputs: Any, *, dt_s: float,
                        profile: str = "paper", options: dict[str, Any] | None = None,
                        scales: dict[str, float] | None = None, x0: Any = None,
                        sensors: Any = None, seed: int = 0, ambient_noise: float = 0.0,
                        noise_free: bool = False, settle_s: float = 0.0) -> Recording:
    """A recording of a simulated unit.

    Parameters
    ----------
    rig_cls : type
    inputs : ndarray, shape (N, nu), or (n_samples, callable)
        ``inputs[k]`` held over ``[t_k, t_{k+1})``; or a closed loop: ``(N, controller)``
        with ``controller(k, y_k) -> u_k`` (the recorded channels at sample ``k``).
    dt_s : float
        Sample period, s.
    profile : str
    options : dict, optional
    scales : dict, optional
        The unit's hidden parameter scale factors.
    x0 : ndarray, optional
        Initial state (default the rig's ``default_x0``).
    sensors : Sensor or str, optional
        Sensor suite or preset (default the profile's).
    seed : int
        Seeds the unit's noise (sensor noise, biases drawn at reset, step noise).
    ambient_noise : float
        Scale of the rig's ambient disturbance (0: none).
    noise_free : bool
        Record the core channels without noise (the suite's quantization, noise, biases and
        delays left out).
    settle_s : float
        Simulated before the recording starts, with the first input held (a rig resting on
        its stops settles into them), s.

    Returns
    -------
    Recording
        ``meta`` holds the rig, profile and seed (never the scales).
    """
    import math

    frame_skip = max(1, math.ceil(dt_s / PHYSICS_DT_MAX_S - 1e-9))
    rig = build_rig(rig_cls, dt_s / frame_skip, profile, options)
    if sensors is None or isinstance(sensors, str):
        sensors = rig.sensors(sensors, dt_s=dt_s)
    if noise_free:
        from testbed.identify.channels import channel_plan
        from testbed.sensors import Suite

        cores = []
        for info in channel_plan(sensors).values():
            if all(c is not info.core for c in cores):
                cores.append(info.core)
        sensors = Suite(*cores)
    dist = rig.disturbance(None, 0.0, ambient_noise)
    sim = Simulator(rig, sensors, 1, frame_skip, disturbance=dist, num_threads=1)
    controller = None
    if isinstance(inputs, tuple):
        n_total, controller = inputs
        inputs = np.zeros((int(n_total), rig.n_actions))
    inputs = np.asarray(inputs, float)
    opts: dict[str, Any] = {"x0": rig.default_x0() if x0 is None else x0}
    if scales:
        opts["params"] = dict(scales)
    sim.reset(seeds=[int(seed)], options=opts)
    first = np.zeros((1, rig.n_actions)) if controller is not None else inputs[:1]
    for _ in range(int(round(settle_s / dt_s))):
        sim.step(first)
    n = len(inputs)
    obs = np.empty((n, sensors.dim))
    obs[0] = sim.obs[0]
    for k in range(n - 1):
        if controller is not None:
            inputs[k] = np.clip(controller(k, obs[k]), rig.action_low, rig.action_high)
        sim.step(inputs[k:k + 1])
        obs[k + 1] = sim.obs[0]
    if controller is not None:
        inputs[n - 1] = inputs[n - 2]
    t = np.arange(n) * dt_s
    return Recording(time_s=t, inputs={a: inputs[:, i].copy()
                                       for i, a in enumerate(rig.action_names)},
                     channels={c: obs[:, i].copy() for i, c in enumerate(sensors.names)},
                     source=f"<simulated {rig_cls.name} seed {seed}>",
                     meta={"rig": rig_cls.name, "profile": profile, "seed": int(seed)})
