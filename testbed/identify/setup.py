"""The inputs of one identification, checked and read: the free parameters, the options,
the recording through the rig's simulator and sensors, each channel's noise level and what is
fitted per channel (bias, scale, delay), the free parameters as :mod:`mujoco.sysid`
parameters."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from testbed.identify.channels import IdentificationError
from testbed.identify.predict import Problem
from testbed.identify.sensor_model import noise_level, still_segment, still_statistics
from testbed.identify.simulate import RecordingModel
from testbed.io.recording import Recording
from testbed.rigs.base import Rig

METHODS = ("auto", "output-error", "multiple-shooting")


def checked_free(rig_cls: Any, free: Any) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """The rig's declared identifiable parameters and the free ones (checked, in order).

    Parameters
    ----------
    rig_cls : type
        A :class:`~testbed.rigs.base.Rig` subclass declaring :attr:`Rig.identifiable`.
    free : list of str or None
        The parameters to fit (None: every declared one).

    Returns
    -------
    declared : dict of str to (float, float)
        ``{parameter: (low, high)}``, the bounds as factors of the nominal value.
    free : list of str
        Without repeats, in the given order.

    Raises
    ------
    IdentificationError
        Not a rig, no declared parameters, or an unknown or empty ``free`` (one line).
    """
    if not (isinstance(rig_cls, type) and issubclass(rig_cls, Rig)):
        raise IdentificationError(f"rig must be a testbed Rig subclass, got {rig_cls!r}")
    declared = dict(rig_cls.identifiable)
    if not declared:
        raise IdentificationError(f"rig {rig_cls.name!r} declares no identifiable parameters")
    if free is None:
        free = list(declared)
    elif isinstance(free, str) or not all(isinstance(f, str) for f in free):
        raise IdentificationError(f"free must be a list of parameter names, got {free!r}")
    free = list(dict.fromkeys(free))
    for name in free:
        if name not in declared:
            raise IdentificationError(f"unknown free parameter {name!r} for rig "
                                      f"{rig_cls.name!r}; expected one of {list(declared)}")
    if not free:
        raise IdentificationError("free must name at least one parameter")
    return declared, free


def check_arguments(holdout: Any, fit_scale: Any, method: Any, segment_s: Any,
                     max_delay: Any) -> None:
    """One-line :class:`IdentificationError` for a bad option, before any simulation.

    Parameters
    ----------
    holdout : float
        Held-out fraction, in ``[0, 0.9)``.
    fit_scale : bool or "declared"
    method : {"auto", "output-error", "multiple-shooting"}
    segment_s : float
        Multiple-shooting segment length, s (> 0).
    max_delay : int or None
        Whole samples >= 0.
    """
    if not (isinstance(holdout, int | float) and not isinstance(holdout, bool)
            and 0.0 <= holdout < 0.9):
        raise IdentificationError(f"holdout must be a fraction in [0, 0.9), got {holdout!r}")
    if fit_scale not in (True, False, "declared"):
        raise IdentificationError(f"fit_scale must be True, False or 'declared', got "
                                  f"{fit_scale!r}")
    if method not in METHODS:
        raise IdentificationError(f"method must be one of {METHODS}, got {method!r}")
    if not (isinstance(segment_s, int | float) and np.isfinite(segment_s) and segment_s > 0):
        raise IdentificationError(f"segment_s must be a positive time in s, got {segment_s!r}")
    if max_delay is not None and (isinstance(max_delay, bool) or not isinstance(max_delay, int)
                                  or max_delay < 0):
        raise IdentificationError(f"max_delay must be whole samples >= 0, got {max_delay!r}")


@dataclasses.dataclass
class FitSetup:
    """What every round of one fit shares: the recording's model, the fitted part, the
    channels' noise levels and what is fitted per channel, the free parameters.

    Attributes
    ----------
    model : RecordingModel
    free : list of str
    bounds : dict of str to (float, float)
        The free parameters' bounds, factors of nominal.
    pdict : mujoco.sysid.ParameterDict
        The free scale factors (``frozen`` once held at nominal).
    held : dict of str to float
        Parameters held at nominal (scale 1), filled as the fit flags them.
    n_fit, segment_len : int
        Samples fitted; multiple-shooting segment, samples.
    sigma : ndarray, shape (m,)
        Noise levels the residuals are divided by (channel units).
    fit_bias, fit_scale : ndarray of bool, shape (m,)
    max_delays : ndarray of int, shape (m,)
    still : (int, int) or None
        The still segment's samples ``[a, b)``.
    still_bias, still_std : ndarray, shape (m,)
        Its biases and noise (nan without one).
    x0_bias : ndarray, shape (m,)
        The bias the initial states are read with at the start.
    x0_fixed : bool
        With a still segment: the initial states' bias stays fixed.
    max_iterations : int
    """

    model: RecordingModel
    free: list[str]
    bounds: dict[str, tuple[float, float]]
    pdict: Any  # mujoco.sysid.ParameterDict of the free scale factors
    held: dict[str, float]  # parameters held at nominal (scale 1), filled as they are flagged
    n_fit: int
    segment_len: int
    sigma: np.ndarray  # (m,) noise levels the residuals are divided by
    fit_bias: np.ndarray  # (m,) bool
    fit_scale: np.ndarray  # (m,) bool
    max_delays: np.ndarray  # (m,) int
    still: tuple[int, int] | None
    still_bias: np.ndarray  # (m,) nan without a still segment
    still_std: np.ndarray  # (m,)
    x0_bias: np.ndarray  # (m,) the bias the initial states are read with at the start
    x0_fixed: bool
    max_iterations: int

    @property
    def m(self) -> int:
        return self.model.y.shape[1]

    def problem(self, names: list[str], method: str, delay: np.ndarray,
                x0_bias: np.ndarray) -> Problem:
        """The least-squares problem of one round over ``names``."""
        return Problem(self.model, names, self.held, method, self.segment_len, self.n_fit,
                       self.sigma, self.fit_bias, self.fit_scale, delay, x0_bias)


def prepare(rig_cls: type[Rig], recording: Recording, declared: dict[str, tuple[float, float]],
             free: list[str], sysid: Any, *, profile: str, options: dict[str, Any] | None,
             sensors: Any, channels: Any, holdout: float, fit_scale: bool | str,
             max_delay: int | None, segment_s: float, max_iterations: int) -> FitSetup:
    """The recording read through the rig's simulator and sensors, the channels' fit flags,
    their noise levels (from a still segment where there is one) and the free parameters.

    Parameters
    ----------
    rig_cls, recording
        As in :func:`~testbed.identify.fit.identify`.
    declared : dict
        :func:`checked_free`'s declared bounds.
    free : list of str
    sysid : module
        :mod:`mujoco.sysid`.
    profile, options, sensors, channels, holdout, fit_scale, max_delay, segment_s
        As in :func:`~testbed.identify.fit.identify` (checked by :func:`check_arguments`).
    max_iterations : int
        Largest number of residual evaluations per least-squares round.

    Returns
    -------
    FitSetup

    Raises
    ------
    IdentificationError
        Fewer than 20 samples to fit.
    """
    model = RecordingModel(rig_cls, recording, profile=profile, options=options,
                           sensors=sensors, channels=channels)
    N, m = model.y.shape
    n_fit = int(math.floor(N * (1.0 - holdout)))
    segment_len = max(int(round(segment_s / model.dt_s)), 10)
    if n_fit < max(20, 2 * min(segment_len, n_fit)) and n_fit < 20:
        raise IdentificationError(f"recording {recording.source}: {n_fit} samples to fit; "
                                  "need at least 20")
    infos = model.infos
    steps = model.steps
    # a quantized position of a joint without limits (a yaw encoder) is known to a step: its
    # offset is fitted (a free joint's offset changes no dynamics); on a limited joint the
    # position against the stop is physics and stays as measured
    limited = {i for i, _, _ in model._ranges}
    fit_bias = np.array([i.bias or (steps[c] > 0 and i.direct_state is not None
                                    and i.direct_state < model.j
                                    and i.direct_state not in limited)
                         for c, i in enumerate(infos)])
    if fit_scale == "declared":  # the sensors' declared sensitivity errors
        fit_scale_v = np.array([i.scale for i in infos])
    else:
        fit_scale_v = np.full(m, bool(fit_scale)) & np.array([i.direct_state is None
                                                              for i in infos])
    max_delays = np.array([i.max_delay if max_delay is None else max_delay for i in infos])
    still, sigma, still_bias, still_std = still_sensor_model(model, n_fit, fit_bias)
    x0_bias = np.where(np.isfinite(still_bias) & model.x0_bias_mask, still_bias, 0.0)
    bounds = {n: declared[n] for n in free}
    pdict = sysid.ParameterDict()
    for name in free:
        lo, hi = bounds[name]
        pdict.add(sysid.Parameter(name, 1.0, lo, hi))
    # with a still segment the initial states are read with its biases, fixed: the fit's
    # own bias and the states read with it could feed each other (a wrong roll from a
    # wrongly biased accelerometer); without one they follow the fit's rounds
    return FitSetup(model=model, free=free, bounds=bounds, pdict=pdict, held={}, n_fit=n_fit,
                  segment_len=segment_len, sigma=sigma, fit_bias=fit_bias,
                  fit_scale=fit_scale_v, max_delays=max_delays, still=still,
                  still_bias=still_bias, still_std=still_std, x0_bias=x0_bias,
                  x0_fixed=still is not None, max_iterations=max_iterations)


def still_sensor_model(model: RecordingModel, n_fit: int, fit_bias: np.ndarray
                        ) -> tuple[tuple[int, int] | None, np.ndarray, np.ndarray, np.ndarray]:
    """The still segment and the channels' noise levels.

    Parameters
    ----------
    model : RecordingModel
    n_fit : int
        Samples fitted.
    fit_bias : ndarray of bool, shape (m,)
        Channels whose bias is fitted (the still segment's bias kept on those only).

    Returns
    -------
    still : (int, int) or None
        The still segment's samples ``[a, b)``.
    sigma : ndarray, shape (m,)
        Noise levels (channel units), a quantized channel's scaled by its level changes.
    still_bias, still_std : ndarray, shape (m,)
        The still segment's biases and noise (nan without one).
    """
    m, steps = model.y.shape[1], model.steps
    still = still_segment(model.u, model.y, model.dt_s, steps, n_fit)
    sigma = np.array([noise_level(model.y[:n_fit, c], steps[c]) for c in range(m)])
    still_bias = np.full(m, np.nan)
    still_std = np.full(m, np.nan)
    if still is not None:
        a, b = still
        x_rest = model.initial_states(np.array([a]), np.zeros(m), np.zeros(m, int))[0]
        x_rest[model.j:] = 0.0
        from testbed.identify.channels import measure_noise_free

        rest = measure_noise_free(model.infos, x_rest[None], model.u_prev[a:a + 1],
                                  np.zeros(1))[0]
        still_bias, still_std, _ = still_statistics(model.y[a:b], rest, model.dt_s)
        still_bias = np.where(fit_bias, still_bias, 0.0)
        sigma = np.maximum(sigma, np.maximum(still_std, steps / np.sqrt(12.0)))
    # a quantized channel's error is a function of the signal between level changes (no new
    # information while it stays on a level): its samples count as many as its changes
    for c in np.flatnonzero(steps > 0):
        changes = int(np.count_nonzero(np.diff(model.y[:n_fit, c])))
        sigma[c] *= math.sqrt(n_fit / max(changes, 1))
    return still, sigma, still_bias, still_std
