"""Offscreen rendering of a rig (``mujoco.Renderer``) and videos of runs.

Headless machines need an OpenGL backend chosen before ``mujoco`` is imported:
``MUJOCO_GL=egl`` (GPU or Mesa's EGL) or ``MUJOCO_GL=osmesa`` (software). Importing
:mod:`testbed` sets ``MUJOCO_GL=egl`` when it is unset, there is no ``DISPLAY`` (Linux) and
``mujoco`` is not imported yet.

Each rig names its camera in its MJCF (:attr:`testbed.rigs.base.Rig.render_camera`); the
image size is the model's offscreen buffer (``<visual><global offwidth offheight>``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import mujoco
import numpy as np

from testbed.io import atomic_path
from testbed.rigs.base import Rig

#: Frame rate of videos of runs (frames are taken every ``round(1 / (dt * fps))`` steps).
VIDEO_FPS = 30.0


class RigRenderer:
    """RGB images of a rig at given states, from its documented camera.

    Parameters
    ----------
    rig : Rig
    camera : str, optional
        A camera of the MJCF (default: the rig's :attr:`~Rig.render_camera`; "" = MuJoCo's
        free camera).

    Raises
    ------
    RuntimeError
        No OpenGL backend (the message says how to choose one).
    """

    def __init__(self, rig: Rig, camera: str | None = None):
        self.rig = rig
        self.camera = rig.render_camera if camera is None else camera
        if self.camera and mujoco.mj_name2id(rig.model, mujoco.mjtObj.mjOBJ_CAMERA,
                                             self.camera) < 0:
            raise ValueError(f"rig {rig.name!r} has no camera {self.camera!r}")
        self.width = int(rig.model.vis.global_.offwidth)
        self.height = int(rig.model.vis.global_.offheight)
        try:
            check_rendering()
            self._renderer = mujoco.Renderer(rig.model, self.height, self.width)
        except Exception as err:  # GL context creation fails in many ways
            raise RuntimeError(f"cannot create an OpenGL context for rendering: {err}") from None
        self._data = mujoco.MjData(rig.model)

    def render(self, x: np.ndarray) -> np.ndarray:
        """The image of the rig at state ``x`` (n,): uint8 array of shape (height, width, 3)."""
        self.rig.set_state(np.asarray(x, float), self._data)
        self._renderer.update_scene(self._data, camera=self.camera if self.camera else -1)
        return self._renderer.render()

    def close(self) -> None:
        """Free the OpenGL context."""
        self._renderer.close()


#: The first failure of :func:`check_rendering` in this process: MuJoCo cannot be asked for an
#: OpenGL context again after one failed (its second ``mjr_makeContext`` aborts the process).
_RENDER_FAILURE: str | None = None


def check_rendering() -> None:
    """Check that an offscreen image can be rendered here (an OpenGL context is created and
    freed), before any work.

    A failure is remembered: later checks in the process raise it again without asking
    OpenGL (MuJoCo aborts the process on a second failed context).

    Raises
    ------
    ValueError
        One line naming ``MUJOCO_GL`` and the cause (an unknown backend, OSMesa or GLFW not
        available, no display, MuJoCo imported before ``testbed`` with ``MUJOCO_GL``
        unset...).
    """
    import os
    import warnings

    from testbed import _startup

    global _RENDER_FAILURE
    hint = ("set MUJOCO_GL=egl (a GPU or Mesa's EGL) or MUJOCO_GL=osmesa (software; needs "
            "libOSMesa)")
    if _startup.BAD_MUJOCO_GL is not None:
        raise ValueError(f"{_startup.BAD_MUJOCO_GL}; {hint}")
    if _RENDER_FAILURE is not None:
        raise ValueError(_RENDER_FAILURE)
    current = os.environ.get("MUJOCO_GL", "")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # GLFW's own warnings: the error says it
            model = mujoco.MjModel.from_xml_string("<mujoco/>")
            renderer = mujoco.Renderer(model, 8, 8)
            renderer.close()
    except Exception as err:  # GL context creation fails in many ways
        from testbed.plugins import describe

        _RENDER_FAILURE = (f"cannot render offscreen with MUJOCO_GL={current!r} "
                           f"({describe(err)}); {hint}")
        raise ValueError(_RENDER_FAILURE) from None


def frame_stride(dt_s: float, fps: float = VIDEO_FPS) -> int:
    """Control steps per video frame so the video plays in real time at about ``fps``."""
    return max(1, int(round(1.0 / (dt_s * fps))))


def check_video_path(path: str | Path) -> Path:
    """``path`` if a video can be written there (an ``.mp4`` name, the writer installed).

    Raises
    ------
    ValueError
        Not an ``.mp4`` path, or the video writer (``imageio-ffmpeg``, which ships an
        ffmpeg binary) is not installed: install the ``video`` extra,
        ``pip install -e '.[video]'``.
    """
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise ValueError(f"the video path must end in .mp4, got {str(path)!r}")
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError as err:
        raise ValueError(f"writing a video needs imageio-ffmpeg ({err}); install it with "
                         "pip install -e '.[video]'") from None
    return path


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Write RGB frames (each (height, width, 3) uint8) to an MP4 (H.264) file, atomically.

    Raises
    ------
    ValueError
        See :func:`check_video_path`; or no frames.
    """
    path = check_video_path(path)
    import imageio_ffmpeg

    path.parent.mkdir(parents=True, exist_ok=True)
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise ValueError("a video needs at least one frame")
    height, width = first.shape[:2]
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(str(tmp), (width, height), fps=float(fps),
                                             codec="libx264", quality=7, macro_block_size=8,
                                             output_params=["-f", "mp4"])
        writer.send(None)  # start ffmpeg
        try:
            writer.send(np.ascontiguousarray(first))
            for frame in frames:
                writer.send(np.ascontiguousarray(frame))
        finally:
            writer.close()
    return path


def iter_frames(rig: Rig, states: np.ndarray, stride: int = 1,
                camera: str | None = None) -> Iterator[np.ndarray]:
    """Images of ``states[::stride]`` (T, n), one at a time: (height, width, 3) uint8."""
    renderer = RigRenderer(rig, camera)
    try:
        for x in np.asarray(states)[::stride]:
            yield renderer.render(x)
    finally:
        renderer.close()
