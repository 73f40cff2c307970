"""RGB rendering with the MJCF's "track" camera, and video files from frames.

MuJoCo picks its OpenGL backend from the MUJOCO_GL environment variable when it is first imported;
`humanoid_env` defaults it to "egl" on headless Linux. Without a working backend, `TrackRenderer`
raises a RuntimeError that says so.
"""
from __future__ import annotations

import copy
import os
import warnings
from collections.abc import Iterable
from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt

CAMERA = "track"


#: Scene effects a plain render leaves out: on a software-GL CPU they are nearly all of a small frame's cost.
PLAIN_OFF = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX)


class TrackRenderer:
    """Offscreen renderer of a humanoid's MjData from the tracking camera.

    `plain=True` renders without shadows, reflections, skybox and multisampling, on a private copy of the model
    (the shadow map and sample count are fixed when the GL context is made; a shared model is left as it is):
    ~10-30x cheaper for a small frame, with the body as visible (docs/benchmarks.md, VIRL's video input)."""

    def __init__(self, model: mujoco.MjModel, height: int = 240, width: int = 320, plain: bool = False) -> None:
        if plain:
            model = copy.copy(model)
            model.vis.quality.shadowsize = 0
            model.vis.quality.offsamples = 0
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # backend chatter (GLFWError...); a failure raises below
                self._renderer = mujoco.Renderer(model, height, width)
        except Exception as err:  # any backend failure: missing library, no display, bad MUJOCO_GL
            backend = os.environ.get("MUJOCO_GL", "<unset, so glfw>")
            raise RuntimeError(
                f"no OpenGL renderer available (MUJOCO_GL={backend}): {type(err).__name__}: {err}. "
                "Set MUJOCO_GL=egl (GPU or Mesa EGL) or MUJOCO_GL=osmesa in the environment before mujoco "
                "is first imported (importing humanoid_env first picks egl on headless Linux)."
            ) from err
        self.model = model
        self._poses = mujoco.MjData(model)  # render_qpos's scratch state, made once: it is called per frame
        if plain:
            for flag in PLAIN_OFF:
                self._renderer.scene.flags[flag] = 0

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """(height, width, 3) uint8 image of data's current state; only derived fields of data are touched."""
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        mujoco.mj_camlight(self.model, data)
        self._renderer.update_scene(data, camera=CAMERA)
        return self._renderer.render()

    def render_qpos(self, qpos: np.ndarray) -> np.ndarray:
        """(N, height, width, 3) uint8 images of poses (N, nq), kinematically (no physics): a clip played back."""
        out = []
        for q in np.asarray(qpos):  # one scene per pose: MuJoCo's renderer is not batched
            self._poses.qpos[:] = q
            out.append(self.render(self._poses))
        return np.stack(out)

    def close(self) -> None:
        self._renderer.close()


def renderer_available() -> bool:
    """Whether an offscreen renderer can be created in this process."""
    from humanoid_env.model import load_model

    try:
        TrackRenderer(load_model(), 16, 16).close()
    except RuntimeError:
        return False
    return True


def write_video(frames: Iterable[np.ndarray], path: str | Path, fps: int = 30) -> Path:
    """Write (H,W,3) uint8 frames to a video file (format from the suffix, e.g. .mp4 via ffmpeg)."""
    import imageio.v2 as imageio

    arrays = [np.asarray(f) for f in frames]
    if not arrays:
        raise ValueError("write_video: no frames to write")
    if any(f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8 for f in arrays):
        raise ValueError("write_video: frames must be (H, W, 3) uint8 arrays")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ims: list[npt.ArrayLike] = list(arrays)  # imageio's stub takes an invariant List[ArrayLike]
    imageio.mimwrite(path, ims, fps=fps)
    return path
