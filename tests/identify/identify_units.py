"""Simulated units for the identification tests: rigs at hidden parameter scales, driven and
recorded like a real unit (the simulator, the rig's sensors, their noise). Imported by the
tests as ``identify_units`` (this folder is put on ``sys.path`` by its ``conftest.py``)."""

from __future__ import annotations

import numpy as np

from testbed.identify.synthetic import random_steps, simulated_recording
from testbed.rigs.aero import AeroRig
from testbed.rigs.helicopter.rig import HelicopterParams, HelicopterRig, gravity_voltage
from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.rigs.vehicle_roll.rig import VehicleRollRig

HELI_FREE = ("pitch_damping", "yaw_damping", "pitch_inertia", "yaw_inertia", "K_pp", "K_yy")
VEHICLE_FREE = ("roll_stiffness", "roll_damping", "com_height_m")
TINY_FREE = ("mass_kg", "stiffness_n_m", "damping_n_s_m")
#: The Aero's (yaw locked: the pitch row only, whose inertia is seen only in ratios and is not
#: free; free: the yaw row too, at its nominal inertia).
AERO_LOCKED_FREE = ("pitch_stiffness", "pitch_damping", "K_pp", "K_py",
                    "rotor_time_constant_pitch_s")
AERO_FREE = AERO_LOCKED_FREE + ("yaw_damping", "K_yp", "K_yy")


class TinyRig(LinearPlantRig):
    """The calibration plant with declared identifiable parameters (a linear rig)."""

    name = "tiny-linear"
    identifiable = {"mass_kg": (0.2, 5.0), "stiffness_n_m": (0.2, 5.0),
                    "damping_n_s_m": (0.2, 5.0)}


def draw_scales(rng: np.random.Generator, rig_cls: type, free: tuple[str, ...]) -> dict:
    """Hidden scales, log-uniform in [0.5, 2] within the declared bounds (10 % inside)."""
    out = {}
    for name in free:
        lo, hi = rig_cls.identifiable[name]
        a, b = max(0.5, lo * 1.1), min(2.0, hi / 1.1)
        out[name] = float(np.exp(rng.uniform(np.log(a), np.log(b))))
    return out


def helicopter_controller(rng: np.random.Generator, dt_s: float, n: int, still_s: float = 0.5):
    """A PID loop on pitch and yaw about random setpoint steps, gravity compensated with the
    nominal parameters (the unit's own differ): a closed-loop recording."""
    nominal = HelicopterParams()
    inverse = np.linalg.inv(nominal.torque_gains)
    ref = np.zeros((n, 2))
    k = int(still_s / dt_s)
    first = k
    while k < n:
        hold = int(rng.uniform(0.5, 1.5) / dt_s)
        ref[k:k + hold] = [rng.uniform(-0.35, 0.3), rng.uniform(-1.0, 1.0)]
        k += hold

    integral = np.zeros(2)

    def control(k: int, y: np.ndarray) -> np.ndarray:
        if k < first:
            return np.zeros(2)
        pitch, yaw, pitch_rate, yaw_rate = y[:4]
        error = ref[k] - np.array([pitch, yaw])
        integral[:] = np.clip(integral + error * dt_s, -0.5, 0.5)  # lifts a weak unit
        torque = np.array([nominal.pitch_inertia * (25 * error[0] + 20 * integral[0]
                                                    - 8 * pitch_rate),
                           nominal.yaw_inertia * (9 * error[1] + 3 * integral[1]
                                                  - 5 * yaw_rate)])
        return gravity_voltage(nominal, pitch) + inverse @ torque

    return control


def helicopter_unit(seed: int, duration_s: float = 4.0, dt_s: float = 0.002,
                    noise_free: bool = False, scales: dict | None = None):
    """A closed-loop recording of a helicopter (hardware profile) at hidden scales, encoders
    and gyros: ``(recording, scales)``."""
    rng = np.random.default_rng(1000 + seed)
    scales = draw_scales(rng, HelicopterRig, HELI_FREE) if scales is None else scales
    n = int(round(duration_s / dt_s))
    rec = simulated_recording(HelicopterRig, (n, helicopter_controller(rng, dt_s, n)),
                              dt_s=dt_s, profile="hardware", scales=scales, seed=seed,
                              sensors="encoders+gyros", noise_free=noise_free, settle_s=0.5)
    return rec, scales


def vehicle_unit(seed: int, duration_s: float = 8.0, dt_s: float = 0.01,
                 noise_free: bool = False, scales: dict | None = None,
                 free: tuple[str, ...] = VEHICLE_FREE, scale_errors: bool = True):
    """Random lateral-acceleration steps on a vehicle (hardware profile: the ``hardware``
    sensor preset, its sensitivity errors left out with ``scale_errors=False``; noise-free:
    the ``imu`` preset's channels): ``(recording, scales)``."""
    rng = np.random.default_rng(2000 + seed)
    scales = draw_scales(rng, VehicleRollRig, free) if scales is None else scales
    n = int(round(duration_s / dt_s))
    u = random_steps(rng, n, dt_s, [-7.0], [7.0], hold_s=(0.15, 0.8), still_s=1.0)
    sensors = None
    if noise_free:
        sensors = "imu"
    elif not scale_errors:
        sensors = VehicleRollRig(profile="hardware").sensors(
            "hardware", dt_s=dt_s, scale_factor_std=0.0, speed_scale_std=0.0)
    rec = simulated_recording(VehicleRollRig, u, dt_s=dt_s, profile="hardware", scales=scales,
                              seed=seed, sensors=sensors, noise_free=noise_free)
    return rec, scales


def tiny_unit(seed: int, duration_s: float = 6.0, dt_s: float = 0.01, sensors=None,
              scales: dict | None = None, still_s: float = 1.0):
    """Random force steps on the tiny linear rig: ``(recording, scales)``."""
    rng = np.random.default_rng(3000 + seed)
    scales = draw_scales(rng, TinyRig, TINY_FREE) if scales is None else scales
    n = int(round(duration_s / dt_s))
    u = random_steps(rng, n, dt_s, [-5.0], [5.0], hold_s=(0.3, 1.2), still_s=still_s)
    rec = simulated_recording(TinyRig, u, dt_s=dt_s, scales=scales, seed=seed, sensors=sensors)
    return rec, scales


def aero_unit(seed: int, locked: bool, duration_s: float = 4.0, dt_s: float = 0.002,
              scales: dict | None = None):
    """Random voltage steps on an Aero (hardware profile, its default sensors: encoders,
    IMU, rotor speeds and currents), yaw locked or free: ``(recording, scales)``."""
    rng = np.random.default_rng(4000 + seed + (100 if locked else 0))
    free = AERO_LOCKED_FREE if locked else AERO_FREE
    scales = draw_scales(rng, AeroRig, free) if scales is None else scales
    n = int(round(duration_s / dt_s))
    u = random_steps(rng, n, dt_s, [-8.0, -8.0], [12.0, 8.0], hold_s=(0.1, 0.6), still_s=0.5)
    rec = simulated_recording(AeroRig, u, dt_s=dt_s, profile="hardware",
                              options={"yaw_locked": locked}, scales=scales, seed=seed)
    return rec, scales
