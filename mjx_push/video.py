"""Replay MJX trajectories in CPU MuJoCo's renderer: top and under-table views side by side.

MJX has no renderer, so an evaluation records each episode's joint positions per environment step and
this module poses the same scene (one builder serves both simulators) frame by frame. Writing .gif
needs only imageio (a dependency of the package); .mp4 also needs the `imageio-ffmpeg` package (the
`mp4` extra). `check_writable` says what is missing before any work is done.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from mjx_push import scene
from mjx_push.renderer import new_renderer
from mjx_push.errors import ConfigError

VIEWS = ("top", "under_table")


class EpisodeRenderer:
    """Renders (H, 2W, 3) frames of qpos sequences for objects of any size; one model per geom type."""

    def __init__(self, height: int = 240, width: int = 320):
        self.height, self.width = height, width
        self._models: dict[str, tuple] = {}

    def _scene(self, geom_type: str):
        if geom_type not in self._models:
            m = scene.build_model(geom_type)
            self._models[geom_type] = (
                m,
                mujoco.MjData(m),
                new_renderer(m, self.height, self.width),
                scene.scene_ids(m),
            )
        return self._models[geom_type]

    def frames(self, geom_type: str, size: np.ndarray, goal: np.ndarray, qpos: np.ndarray) -> list[np.ndarray]:
        """`size`: the object's geom size (3,); `goal`: (x, y, yaw), drawn as a marker; `qpos`: [T, nq]."""
        m, d, r, ids = self._scene(geom_type)
        m.geom_size[ids.object_geom] = size
        out = []
        for q in np.asarray(qpos):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_camlight(m, d)
            views = []
            for cam in VIEWS:
                r.update_scene(d, camera=cam)
                _goal_marker(r.scene, goal, size, geom_type)
                views.append(r.render().copy())
            out.append(np.concatenate(views, axis=1))
        return out

    def close(self):
        for _, _, r, _ in self._models.values():
            r.close()
        self._models.clear()


def _goal_marker(scn, goal: np.ndarray, size: np.ndarray, geom_type: str) -> None:
    """A translucent green ghost of the object at the goal pose (visual only, not simulated)."""
    if scn.ngeom >= scn.maxgeom:
        return
    g = scn.geoms[scn.ngeom]
    c, s = np.cos(goal[2]), np.sin(goal[2])
    mat = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)
    half_h = size[2] if geom_type == "box" else size[1]
    gtype = mujoco.mjtGeom.mjGEOM_BOX if geom_type == "box" else mujoco.mjtGeom.mjGEOM_CYLINDER
    mujoco.mjv_initGeom(
        g,
        gtype,
        np.asarray(size, np.float64),
        np.array([goal[0], goal[1], scene.TABLE_TOP + half_h], np.float64),
        mat.flatten(),
        np.array([0.1, 0.9, 0.2, 0.35], np.float32),
    )
    scn.ngeom += 1


SUFFIXES = (".gif", ".mp4")


def check_writable(path: Path) -> None:
    """Raise ValueError, saying what to install or change, unless a video can be written to `path`
    (call it before the work whose frames it will hold)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ConfigError(f"{path} must end in .gif or .mp4")
    try:
        import imageio.v2  # noqa: F401
    except ImportError:
        raise ConfigError("writing videos needs the imageio package: pip install imageio") from None
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ConfigError(
                f"writing {path.name} (.mp4) needs imageio-ffmpeg: pip install 'mjx-push[mp4]' "
                f"(or pip install imageio-ffmpeg), or write a GIF: {path.with_suffix('.gif')}"
            ) from None
    if path.is_dir():
        raise ConfigError(f"{path} is a directory, not a video file")


def write(frames: list[np.ndarray], path: Path, fps: int = 5) -> Path:
    """Write frames to .gif or .mp4 (by suffix). A clear error when the format cannot be written."""
    check_writable(path)
    import imageio.v2 as imageio

    path = Path(path)
    suffix = path.suffix.lower()
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        imageio.mimsave(path, frames, duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(path, frames, fps=fps)
    return path
