"""Analytic masks against MuJoCo's own renderer (docs/task.md section 2): mean IoU >= 0.95 over random poses."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_push import masks, scene
from tests.helpers import no_renderer

N_PER_SHAPE = 120  # 240 poses in all


def _renderer(m):
    try:
        return mujoco.Renderer(m, scene.IMAGE_SIZE, scene.IMAGE_SIZE)
    except Exception as e:  # no EGL / OSMesa on this machine
        no_renderer(f"{type(e).__name__}: {e}")


def colour_filter(rgb: np.ndarray) -> np.ndarray:
    """The reference's filter: strongly blue pixels are the object."""
    rgb = rgb.astype(int)
    return (rgb[..., 2] > 128) & (rgb[..., 0] < 80) & (rgb[..., 1] < 80)


@pytest.mark.renderer
@pytest.mark.parametrize("shape", scene.SHAPES)
def test_masks_match_renderer(shape):
    rng = np.random.default_rng(42 if shape == "box" else 7)
    m = scene.build_model(shape)
    ids = scene.scene_ids(m)
    d = mujoco.MjData(m)
    r = _renderer(m)
    sizes, poses, zs, refs = [], [], [], []
    home = scene.home_flange_pos()[:2]
    try:
        for _ in range(N_PER_SHAPE):
            if shape == "box":
                size = np.array([rng.uniform(0.025, 0.055), rng.uniform(0.025, 0.055), rng.uniform(0.023, 0.04)])
                hh = size[2]
            else:
                size = np.array([rng.uniform(0.04, 0.055), rng.uniform(0.023, 0.0275), 0.0])
                hh = size[1]
            # Positions over the encoder's training range (docs/task.md section 5): wider than the task's.
            xy = home + np.array([rng.uniform(-0.25, 0.30), rng.uniform(-0.30, 0.30)])
            yaw = rng.uniform(-np.pi, np.pi)
            m.geom_size[ids.object_geom] = size
            d.qpos[:7] = scene.HOME_QPOS
            d.qpos[ids.object_qpos : ids.object_qpos + 7] = [
                xy[0],
                xy[1],
                scene.TABLE_TOP + hh,
                np.cos(yaw / 2),
                0,
                0,
                np.sin(yaw / 2),
            ]
            mujoco.mj_forward(m, d)
            r.update_scene(d, camera="under_table")
            refs.append(colour_filter(r.render()))
            sizes.append(size)
            poses.append([xy[0], xy[1], yaw])
            zs.append(scene.TABLE_TOP + hh)
    finally:
        r.close()
    f = lambda x: jnp.asarray(np.array(x), jnp.float32)  # noqa: E731
    poses = f(poses)
    ana = jax.jit(jax.vmap(lambda s, p, z: masks.object_mask(shape, s, p[:2], p[2], z)))(f(sizes), poses, f(zs))
    ana = np.asarray(ana)
    refs = np.stack(refs)
    inter = (ana & refs).sum((1, 2))
    union = (ana | refs).sum((1, 2))
    assert np.all(refs.sum((1, 2)) > 10), "the renderer must see every object"
    iou = inter / union
    assert iou.mean() >= 0.95, f"mean IoU {iou.mean():.4f}"
    assert ana.shape == (N_PER_SHAPE, scene.IMAGE_SIZE, scene.IMAGE_SIZE)


def test_pixel_convention():
    """Columns grow with world +x, rows with world +y; the principal point is the image centre."""
    f = lambda *x: jnp.asarray(x, jnp.float32)  # noqa: E731
    cx, cy = scene.CAMERA_POS[:2]
    size = f(0.02, 0.02, 0.02)
    centre = np.argwhere(np.asarray(masks.object_mask("box", size, f(cx, cy), 0.0, scene.TABLE_TOP + 0.02))).mean(0)
    np.testing.assert_allclose(centre, [31.5, 31.5], atol=0.01)
    right = np.argwhere(np.asarray(masks.object_mask("box", size, f(cx + 0.1, cy), 0.0, scene.TABLE_TOP + 0.02))).mean(
        0
    )
    down = np.argwhere(np.asarray(masks.object_mask("box", size, f(cx, cy + 0.1), 0.0, scene.TABLE_TOP + 0.02))).mean(0)
    assert right[1] > centre[1] + 5 and abs(right[0] - centre[0]) < 0.01
    assert down[0] > centre[0] + 5 and abs(down[1] - centre[1]) < 0.01
