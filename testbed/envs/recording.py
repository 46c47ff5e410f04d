"""A Gymnasium wrapper that keeps what the sensors gave as a recording (no truth).

``RecordLog(env, "run.csv")`` records the current episode of a testbed environment and writes
it on :meth:`RecordLog.close` (or on demand: :meth:`RecordLog.recording`,
:meth:`RecordLog.save`), in the layout :func:`testbed.io.formats.read_recording` reads: what a
real unit's log would hold. The true state, the disturbance and the estimate are never kept.

Rows follow a real rig's log (:mod:`testbed.io.formats`) and are those of ``testbed run
--save-log`` (one definition: :func:`testbed.experiment.replay.episode_recording`): row ``k``
holds the time ``k dt_s`` after the reset or step ``k`` (``info["t"]``), the measurement then,
and the input applied over the next step (``info["action_applied"]`` of step ``k + 1``: after
clipping, the manoeuvre's part included); an episode of ``T`` steps gives ``T + 1`` samples,
the last row's input repeating the one before it (no step follows it).

Multi-rate sensors: a sensor slower than the loop (:class:`~testbed.sensors.SampleAndHold`,
the helicopter's IMU) gives its last sample again until it takes a new one, so every step
has a value (no NaN). The recording keeps exactly those held values, as a data logger
sampling at the loop rate would.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from testbed.envs.common import env_declarations
from testbed.io import check_output_path
from testbed.io.formats import SUFFIXES, check_recording, write_recording
from testbed.io.recording import Recording, RecordingError


class RecordLog(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Record the measurements and the applied inputs of the current episode.

    Parameters
    ----------
    env : gymnasium.Env
        A testbed environment (possibly wrapped): ``info`` with ``t`` and
        ``action_applied``; the measurement is ``info["measurement"]`` when a wrapper below
        puts it there (:class:`~testbed.envs.wrappers.FilterInLoop`), else the observation.
        Names: ``env.unwrapped.action_names`` and ``env.unwrapped.sensors.names``.
    path : str or PathLike, optional
        Where :meth:`close` writes the episode (``.csv``, ``.npz`` or ``.mat``; checked
        now). None: nothing is written; use :meth:`recording` or :meth:`save`.
    meta : dict, optional
        Added to the recording's ``meta`` (JSON-serialisable).

    Notes
    -----
    Each ``reset`` starts a new recording (the previous episode is dropped: wrap one
    episode, or call :meth:`save` before resetting). ``close`` writes nothing when no step
    was taken.
    """

    def __init__(self, env: gym.Env, path: str | os.PathLike | None = None, *,
                 meta: dict[str, Any] | None = None):
        gym.utils.RecordConstructorArgs.__init__(self, path=path, meta=meta)
        gym.Wrapper.__init__(self, env)
        if path is not None:
            suffix = Path(os.fspath(path)).suffix.lower()
            if suffix not in SUFFIXES:
                raise ValueError(f"path must end in {', '.join(SUFFIXES)}, got "
                                 f"{os.fspath(path)!r}")
            check_output_path(path, "path", suffix)
        self.path = None if path is None else Path(path)
        inner = env.unwrapped
        declared = env_declarations(inner)
        self.channel_names = declared.channel_names
        self.action_names = tuple(declared.action_names or ())
        if not self.channel_names or not self.action_names:
            raise ValueError("RecordLog needs a testbed environment (env.unwrapped.sensors."
                             "names and env.unwrapped.action_names)")
        self._meta = {"rig": declared.rig_name, "profile": declared.profile,
                      "sensors": declared.sensors_text,
                      "control_dt_s": float(0.0 if declared.dt_s is None else declared.dt_s),
                      **(meta or {})}
        self._t: list[float] = []
        self._y: list[np.ndarray] = []
        self._u: list[np.ndarray] = []
        self._seed: int | None = None

    def _measurement(self, obs: Any, info: dict[str, Any]) -> np.ndarray:
        y = np.array(info["measurement"] if "measurement" in info else obs, dtype=np.float64)
        if y.shape != (len(self.channel_names),):
            raise ValueError(f"RecordLog: the measurement has shape {y.shape}, the sensors "
                             f"declare {len(self.channel_names)} channels (a wrapper below "
                             "changed the observation: put RecordLog under it)")
        return y

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the environment and start a new recording."""
        obs, info = self.env.reset(seed=seed, options=options)
        self._seed = seed
        self._t = [float(info["t"])]
        self._y = [self._measurement(obs, info)]
        self._u = []
        return obs, info

    def step(self, action: Any):
        """Step the environment; keep the applied input and the new measurement."""
        if not self._t:
            raise RuntimeError("RecordLog: call reset() before step()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._u.append(np.array(info["action_applied"], dtype=np.float64))
        self._t.append(float(info["t"]))
        self._y.append(self._measurement(obs, info))
        return obs, reward, terminated, truncated, info

    @property
    def steps(self) -> int:
        """Steps recorded in the current episode."""
        return len(self._u)

    def recording(self, source: str = "<RecordLog>") -> Recording:
        """The current episode as a :class:`~testbed.io.recording.Recording`.

        Returns
        -------
        Recording
            ``steps + 1`` samples (see the module docstring for the rows).

        Raises
        ------
        RecordingError
            No step recorded.
        """
        from testbed.experiment.replay import episode_recording

        n = len(self._u)
        if n < 1:
            raise RecordingError(f"{source}: no step recorded; a recording needs at least 1 "
                                 "step (2 samples)")
        meta = dict(self._meta)
        if self._seed is not None:
            meta["seed"] = int(self._seed)
        rec = episode_recording(np.array(self._y), np.array(self._u), self._meta["control_dt_s"],
                                action_names=self.action_names,
                                channel_names=self.channel_names, meta=meta, source=source)
        return check_recording(rec)

    def save(self, path: str | os.PathLike | None = None) -> Path:
        """Write the current episode (to ``path``, default the wrapper's) atomically."""
        target = path if path is not None else self.path
        if target is None:
            raise ValueError("RecordLog.save: no path (give one here or to RecordLog)")
        return write_recording(target, self.recording(source=os.fspath(target)))

    def close(self) -> None:
        """Write the episode to ``path`` (when given and at least 1 step was recorded),
        then close the environment (also when writing fails)."""
        try:
            if self.path is not None and len(self._u) >= 1:
                self.save()
        finally:
            self._t, self._y, self._u = [], [], []
            self.env.close()
