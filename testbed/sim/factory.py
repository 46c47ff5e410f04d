"""The simulator factory: a :class:`~testbed.sim.simulator.Simulator` from a rig name and
the options of a scenario or a Gymnasium environment (the runner, the environments and the
real-time rig all build their simulator here)."""

from __future__ import annotations

from typing import Any

from testbed.rigs import resolve_rig
from testbed.rigs.base import Rig, build_rig
from testbed.sim.simulator import Simulator, positive_int


def build_simulator(rig: Any = "helicopter", num: int = 1, *, physics_dt_s: float = 0.001,
                    frame_skip: int = 10, sensors: Any = None,
                    sensor_kwargs: dict[str, Any] | None = None, disturbance: Any = None,
                    process_noise: float = 0.0, setpoints: Any = None, manoeuvre: Any = None,
                    manoeuvre_params: dict[str, Any] | None = None,
                    params: dict[str, float] | None = None,
                    num_threads: int | None = None, profile: str = "paper",
                    reset_noise_scale: float = 1.0, ambient_noise: float = 1.0,
                    rig_options: dict[str, Any] | None = None,
                    nominal_params: Any = None) -> Simulator:
    """A :class:`Simulator` of ``num`` members from the environments' arguments.

    ``rig`` is a registered name, a class or a built :class:`~testbed.rigs.base.Rig` (used as
    it is; ``physics_dt_s`` and ``profile`` are then the rig's own). By default the initial
    state is drawn from the rig's documented distribution
    (``reset_noise_scale = 1``) and the rig's small ambient disturbance is on
    (``ambient_noise = 1``); 0 turns either off. ``rig_options`` and ``nominal_params`` (the
    rig's ``Params``, e.g. a twin's) build a rig from its name or class.
    """
    positive_int(frame_skip, "frame_skip")
    if isinstance(rig, Rig):
        rig_obj = rig  # built already (Scenario.check): the MJCF is not read again
    else:
        rig_obj = build_rig(resolve_rig(rig), nominal_params, physics_dt_s=physics_dt_s,
                            profile=profile, options=rig_options)
    dt_s = rig_obj.model.opt.timestep * int(frame_skip)
    if sensors is None or isinstance(sensors, str):
        sensors = rig_obj.sensors(sensors, dt_s=dt_s, **(sensor_kwargs or {}))
    elif sensor_kwargs:
        raise ValueError("sensor_kwargs is only used with a sensor preset name")
    dist = rig_obj.disturbance(disturbance, process_noise, ambient_noise)
    return Simulator(rig_obj, sensors, num, frame_skip, disturbance=dist, params=params,
                     setpoints=setpoints, manoeuvre=manoeuvre,
                     manoeuvre_params=manoeuvre_params, num_threads=num_threads,
                     reset_noise_scale=reset_noise_scale)
