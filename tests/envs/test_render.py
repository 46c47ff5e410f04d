"""Rendering: ``render_mode="rgb_array"``, Gymnasium's RecordVideo, ``testbed run --video``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import testbed  # noqa: F401  (registers the environments; sets MUJOCO_GL=egl when headless)
from testbed.cli import main
from testbed.envs import RigEnv


def _env(rig: str, **kwargs) -> RigEnv:
    try:
        env = RigEnv(rig, render_mode="rgb_array", **kwargs)
        env.reset(seed=0)
        env.render()
    except RuntimeError as err:
        if "OpenGL" in str(err):
            pytest.skip(f"no OpenGL backend for MuJoCo on this machine: {err}")
        raise
    return env


@pytest.mark.parametrize("rig, x_a, x_b", [
    ("helicopter", [-0.7, 0.0, 0, 0], [0.3, 1.0, 0, 0]),
    ("vehicle-roll", [0.0, 0.0], [0.15, 0.0]),
])
def test_rgb_array_shows_the_pose(rig, x_a, x_b):
    env = _env(rig)
    assert env.metadata["render_fps"] == pytest.approx(100.0)
    env.reset(seed=0, options={"x0": x_a})
    a = env.render()
    env.reset(seed=0, options={"x0": x_b})
    b = env.render()
    assert a.shape == (480, 640, 3) and a.dtype == np.uint8
    assert a.std() > 10  # not a blank image
    changed = np.any(a != b, axis=2).mean()
    assert 0.005 < changed < 0.5  # the rig moved, the scene did not
    np.testing.assert_array_equal(env.render(), b)  # deterministic
    env.close()


def test_render_mode_errors():
    with pytest.raises(ValueError, match="render_mode must be None or 'rgb_array'"):
        RigEnv("helicopter", render_mode="human")
    env = RigEnv("helicopter")
    env.reset(seed=0)
    assert env.render() is None


def test_record_video_wrapper(tmp_path):
    pytest.importorskip("moviepy", reason="Gymnasium's RecordVideo needs moviepy (test extra)")
    _env("helicopter").close()
    env = gym.make("testbed/Helicopter2DOF-v0", render_mode="rgb_array", max_episode_steps=8)
    env = gym.wrappers.RecordVideo(env, str(tmp_path), episode_trigger=lambda e: True,
                                   disable_logger=True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([12.0, -3.0]))
        done = terminated or truncated
    env.close()
    videos = list(tmp_path.glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000


def test_cli_video(tmp_path, capsys):
    ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="--video needs imageio-ffmpeg "
                                                          "(video extra)")
    _env("vehicle-roll").close()
    path = tmp_path / "v.mp4"
    assert main(["run", "vehicle-roll", "--duration", "0.3", "--video", str(path),
                 "--no-progress"]) == 0
    reader = ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    assert meta["size"] == (640, 480) and meta["fps"] == pytest.approx(100 / 3, rel=1e-2)
    assert frames == 11  # 31 states, every third
    assert main(["run", "vehicle-roll", "--duration", "1", "--video",
                 str(tmp_path / "v.gif")]) == 2
    assert "--video must be a .mp4 file" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_a_failed_opengl_context_is_one_line_every_time_not_an_abort():
    """MuJoCo imported before testbed on a headless machine (MUJOCO_GL unset): rendering
    fails with the one-line message, and so does a second env (MuJoCo aborts the process
    on a second failed context: the first failure is remembered)."""
    import os
    import subprocess
    import sys

    code = ("import mujoco, gymnasium as gym, testbed\n"
            "for _ in range(3):\n"
            "    try:\n"
            "        gym.make('testbed/Helicopter2DOF-v0', render_mode='rgb_array')\n"
            "    except ValueError as exc:\n"
            "        print(str(exc).splitlines()[0][:80])\n")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY",
                                                            "PYOPENGL_PLATFORM")}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-500:]
    lines = done.stdout.splitlines()
    assert len(lines) == 3 and len(set(lines)) == 1
    assert lines[0].startswith("render_mode='rgb_array': cannot render offscreen with "
                               "MUJOCO_GL=''")
