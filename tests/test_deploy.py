"""The camera pipeline (mjx_push.export.camera) on synthetic images and the deployment loop (mjx_push.export.deploy)."""

import colorsys

import jax
import numpy as np
import pytest
from scipy import ndimage

from mjx_push.export.camera import MaskPipeline, dilate, erode, resize_area, resize_nearest, rgb_to_hsv
from mjx_push.export.cpu_env import CpuPushEnv, render_filter
from mjx_push.export.deploy import Camera, Policy, Robot, SimCamera, SimRobot, run_episode
from mjx_push import mask_geometry, scene
from tests.helpers import HOME_XY, a_s_for, make_params, renderer_or_skip

BLUE = (0, 0, 255)
N = scene.IMAGE_SIZE


def image(h, w, boxes=(), colour=BLUE, background=(20, 20, 20)):
    """(h, w, 3) uint8 with `colour` on the half-open pixel boxes (top, left, bottom, right)."""
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background
    for top, left, bottom, right in boxes:
        img[top:bottom, left:right] = colour
    return img


def box_mask(h, w, boxes):
    m = np.zeros((h, w), bool)
    for top, left, bottom, right in boxes:
        m[top:bottom, left:right] = True
    return m


# --- MaskPipeline on synthetic images ------------------------------------------------------------------
def test_default_threshold_is_the_simulator_filter():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (N, N, 3), dtype=np.uint8)
    rgb[10:30, 5:40] = BLUE
    np.testing.assert_array_equal(MaskPipeline().to_mask(rgb), render_filter(rgb))
    boxes = [(10, 5, 30, 40)]
    np.testing.assert_array_equal(MaskPipeline().to_mask(image(N, N, boxes)), box_mask(N, N, boxes))


def test_crop_and_flips():
    # A 100x120 frame; the crop (20, 30, 84, 94) is exactly 64x64 so no resampling happens.
    boxes = [(25, 40, 35, 60)]
    rgb = image(100, 120, boxes + [(0, 0, 10, 10)])  # a blue patch outside the crop must vanish
    expect = box_mask(N, N, [(5, 10, 15, 30)])
    crop = (20, 30, 84, 94)
    np.testing.assert_array_equal(MaskPipeline(crop=crop).to_mask(rgb), expect)
    np.testing.assert_array_equal(MaskPipeline(crop=crop, flip_horizontal=True).to_mask(rgb), expect[:, ::-1])
    np.testing.assert_array_equal(MaskPipeline(crop=crop, flip_vertical=True).to_mask(rgb), expect[::-1])
    both = MaskPipeline(crop=crop, flip_horizontal=True, flip_vertical=True).to_mask(rgb)
    np.testing.assert_array_equal(both, expect[::-1, ::-1])


def test_open_removes_speckle_and_close_fills_holes():
    obj = [(10, 10, 30, 40), (40, 0, 64, 12)]  # the second touches the left and bottom borders
    expect = box_mask(N, N, obj)
    noisy = image(N, N, obj)
    for r, c in [(2, 50), (55, 55), (0, 63), (35, 20)]:  # isolated speckles, one in a corner
        noisy[r, c] = BLUE
    noisy[20, 25] = (20, 20, 20)  # a one-pixel hole
    noisy[12:14, 30] = (20, 20, 20)  # a two-pixel crack
    assert not np.array_equal(MaskPipeline().to_mask(noisy), expect)
    cleaned = MaskPipeline(open_size=3, close_size=3).to_mask(noisy)
    np.testing.assert_array_equal(cleaned, expect)
    # Closing alone keeps the speckles, opening alone keeps the hole.
    assert MaskPipeline(close_size=3).to_mask(noisy)[55, 55]
    assert not MaskPipeline(open_size=3).to_mask(noisy)[20, 25]


def test_morphology_matches_scipy():
    rng = np.random.default_rng(1)
    m = rng.random((40, 50)) < 0.4
    for k in (3, 5):
        st = np.ones((k, k), bool)
        np.testing.assert_array_equal(dilate(m, k), ndimage.binary_dilation(m, st, border_value=0))
        np.testing.assert_array_equal(erode(m, k), ndimage.binary_erosion(m, st, border_value=1))


def test_resize_area_and_nearest():
    boxes = [(20, 30, 60, 90), (100, 100, 128, 128)]  # even coordinates: an exact 2x reduction
    big = image(128, 128, boxes)
    expect = box_mask(N, N, [(10, 15, 30, 45), (50, 50, 64, 64)])
    np.testing.assert_array_equal(MaskPipeline().to_mask(big), expect)
    np.testing.assert_array_equal(MaskPipeline(resize="nearest").to_mask(big), expect)
    # Non-integer factor 96 -> 64: each output pixel covers 1.5 x 1.5 input pixels.
    m = np.zeros((96, 96), bool)
    m[:, :48] = True  # left half: output columns 0..31
    np.testing.assert_array_equal(resize_area(m), np.repeat([np.arange(N) < 32], N, axis=0))
    m = np.zeros((96, 96), bool)
    m[:, :1] = True  # 1 of 1.5 pixel widths: 2/3 of output column 0
    assert resize_area(m, threshold=0.6)[:, 0].all() and not resize_area(m, threshold=0.7)[:, 0].any()
    np.testing.assert_array_equal(resize_nearest(np.eye(N, dtype=bool)), np.eye(N, dtype=bool))
    # Upsampling a small crop also works (area weights of an enlargement).
    small = np.zeros((32, 32), bool)
    small[8:16, 8:24] = True
    np.testing.assert_array_equal(resize_area(small), np.kron(small, np.ones((2, 2), bool)))


def test_hsv_default_selects_the_simulator_blue():
    rgb = image(N, N, [(3, 4, 20, 30)])
    rgb[40:50, 40:50] = (120, 120, 200)  # pale blue-grey: low saturation, not the object
    np.testing.assert_array_equal(MaskPipeline(color_space="hsv").to_mask(rgb), box_mask(N, N, [(3, 4, 20, 30)]))


def test_hsv_threshold_and_hue_wrap():
    rng = np.random.default_rng(2)
    rgb = rng.integers(0, 256, (200, 3), dtype=np.uint8)
    hsv = rgb_to_hsv(rgb)
    ref = np.array([colorsys.rgb_to_hsv(*(c / 255.0)) for c in rgb])
    np.testing.assert_allclose(hsv[:, 1:], ref[:, 1:], atol=1e-12)
    np.testing.assert_allclose(hsv[:, 0], ref[:, 0] * 360.0, atol=1e-9)
    # Red wraps through hue 0: (350 deg, 10 deg) are in, cyan (180 deg) and grey are out.
    px = np.array([[[255, 0, 43], [255, 43, 0], [0, 255, 255], [128, 128, 128]]], np.uint8)  # hues ~350, ~10, 180, -
    red = MaskPipeline(color_space="hsv", lower=(340, 0.5, 0.5), upper=(20, 1.0, 1.0))
    np.testing.assert_array_equal(red.threshold(px)[0], [True, True, False, False])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"color_space": "lab"}, "color_space"),
        ({"lower": (0, 0, 300)}, "lower"),
        ({"upper": (0, 0)}, "upper"),
        ({"lower": (100, 0, 0), "upper": (50, 255, 255)}, "lower"),
        ({"color_space": "hsv", "upper": (360, 2.0, 1.0)}, "upper"),
        ({"crop": (10, 10, 5, 20)}, "crop"),
        ({"crop": (0, 0, 10)}, "crop"),
        ({"crop": (-1, 0, 10, 10)}, "crop"),
        ({"open_size": 2}, "open_size"),
        ({"close_size": 0}, "close_size"),
        ({"resize": "bicubic"}, "resize"),
        ({"area_threshold": 0.0}, "area_threshold"),
        ({"flip_vertical": "yes"}, "flip_vertical"),
    ],
)
def test_bad_pipeline_config_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MaskPipeline(**kwargs)


def test_bad_images_name_the_problem():
    pipe = MaskPipeline(crop=(0, 0, 64, 64))
    with pytest.raises(ValueError, match="rgb.*shape"):
        pipe.to_mask(np.zeros((64, 64), np.uint8))
    with pytest.raises(ValueError, match="rgb.*shape"):
        pipe.to_mask(np.zeros((64, 64, 4), np.uint8))
    with pytest.raises(ValueError, match="rgb.*dtype"):
        pipe.to_mask(np.zeros((64, 64, 3), np.float32))
    with pytest.raises(ValueError, match="rgb"):
        pipe.to_mask([[[0, 0, 0]]])
    with pytest.raises(ValueError, match="crop"):
        pipe.to_mask(np.zeros((48, 64, 3), np.uint8))


# --- run_episode with stand-ins (no renderer) -----------------------------------------------------------
class ScriptedPolicy:
    """Fixed (a_x, a_y) every step for `a_s` substeps."""

    def __init__(self, a_x, a_y, a_s):
        self.a, self.resets, self.seen = (a_x, a_y, a_s), 0, []

    def reset(self):
        self.resets += 1

    def act(self, object_mask, goal_mask, ee_xy):
        self.seen.append((object_mask.shape, goal_mask.dtype, np.asarray(ee_xy).shape))
        return self.a


class AnalyticCamera:
    """The object's analytic mask painted blue on grey: a renderer-free camera."""

    def __init__(self, env):
        self.env = env

    def frame(self):
        rgb = np.full((N, N, 3), 90, np.uint8)
        rgb[self.env.object_mask()] = BLUE
        return rgb


def _sim_env(mask_source="analytic", start=(-0.12, -0.1, 0.0)):
    env = CpuPushEnv(geom_type="box", mask_source=mask_source, seed=0)
    env.reset(params=jax.tree.map(np.asarray, make_params("box", start=start)))
    return env


def test_protocols_are_satisfied():
    env = _sim_env()
    assert isinstance(SimRobot(env), Robot) and isinstance(SimCamera(env), Camera)
    assert isinstance(ScriptedPolicy(0, 0, 10), Policy)


def test_run_episode_targets_equal_the_simulator():
    """run_episode + SimRobot drive the arm exactly as CpuPushEnv.step does with the same actions."""
    a_x, a_y, n = 0.04, -0.03, 137
    env = _sim_env()
    policy = ScriptedPolicy(a_x, a_y, n)
    out = run_episode(policy, SimRobot(env), AnalyticCamera(env), MaskPipeline(), env.goal_mask, steps=3)
    assert policy.resets == 1 and policy.seen[0] == ((N, N), np.dtype(bool), (2,))
    ref = _sim_env()
    mask0 = ref.object_mask()
    flange = [ref.flange_pos()]
    for _ in range(3):
        _, _, _, _, info = ref.step(np.array([a_x, a_y, a_s_for(n)]))
        assert info["substeps"] == n
        flange.append(ref.flange_pos())
    flange = np.stack(flange)
    np.testing.assert_array_equal(out["ee_xy"], flange[:, :2])
    expect = np.clip(flange[:-1, :2] + [a_x, a_y], [0.10, -0.25], [0.65, 0.25])
    np.testing.assert_array_equal(out["targets"][:, :2], expect)
    np.testing.assert_allclose(out["targets"][:, 2], scene.home_flange_pos()[2])
    assert out["steps"] == 3 and out["object_masks"].shape == (4, N, N) and out["bad_actions"] == 0
    np.testing.assert_array_equal(out["object_masks"][0], mask0)  # the painted frame through the pipeline


def test_run_episode_sanitises_and_validates_policy_output():
    env = _sim_env()
    robot, cam = SimRobot(env), AnalyticCamera(env)
    out = run_episode(ScriptedPolicy(np.nan, 3.0, 10), robot, cam, MaskPipeline(), env.goal_mask, steps=2)
    assert out["bad_actions"] == 2
    np.testing.assert_array_equal(out["actions"][:, :2], [[0.0, 1.0], [0.0, 1.0]])
    for a_s in (0, 601, 12.5, np.nan):
        with pytest.raises(ValueError, match="a_s"):
            run_episode(ScriptedPolicy(0.0, 0.0, a_s), robot, cam, MaskPipeline(), env.goal_mask, steps=1)
    with pytest.raises(ValueError, match="goal_mask"):
        run_episode(ScriptedPolicy(0.0, 0.0, 10), robot, cam, MaskPipeline(), np.zeros((32, 32)), steps=1)
    with pytest.raises(ValueError, match="workspace"):
        run_episode(ScriptedPolicy(0.0, 0.0, 10), robot, cam, MaskPipeline(), env.goal_mask, workspace=((1, 0), (0, 1)))
    stops = run_episode(
        ScriptedPolicy(0.0, 0.0, 10), robot, cam, MaskPipeline(), env.goal_mask, steps=5, on_step=lambda t, rec: t == 1
    )
    assert stops["steps"] == 2 and stops["ee_xy"].shape == (3, 2)


# --- run_episode with the rendered camera -------------------------------------------------------------
def _mask_centroid_xy(mask, z_mid):
    """World xy of a mask's pixel centroid, back-projected at height z_mid (inverse of the camera model)."""
    r, c = np.argwhere(mask).mean(0) + 0.5 - N / 2
    depth = z_mid - scene.CAMERA_POS[2]
    return scene.CAMERA_POS[:2] + np.array([c, r]) * depth / mask_geometry.FOCAL


class StandOffPolicy:
    """Moves the flange to a point 9 cm from the object's centre (located from the mask alone) on the
    side facing the home position: it approaches the object without touching it."""

    def __init__(self, z_mid):
        self.z_mid, self.targets = z_mid, []

    def reset(self):
        self.targets.clear()

    def act(self, object_mask, goal_mask, ee_xy):
        obj = _mask_centroid_xy(object_mask, self.z_mid)
        away = (HOME_XY - obj) / np.linalg.norm(HOME_XY - obj)
        target = obj + 0.09 * away
        self.targets.append(target)
        a = target - ee_xy
        return float(a[0]), float(a[1]), 600


@pytest.mark.renderer
def test_run_episode_with_rendered_camera():
    renderer_or_skip()
    env = _sim_env("render", start=(0.08, 0.12, 0.4))
    obj0 = env.info()["object_xy"]
    camera = SimCamera(env, size=128)  # a 2x larger frame: the pipeline's area resize is in the loop
    policy = StandOffPolicy(scene.TABLE_TOP + float(env.params.size[2]))
    ious = []
    out = run_episode(
        policy,
        SimRobot(env),
        camera,
        MaskPipeline(),
        env.goal_mask,
        steps=8,
        on_step=lambda t, rec: ious.append(_iou_with_analytic(env, rec["object_mask"])),
    )
    assert min(ious) >= 0.9, f"pipeline vs analytic IoU {min(ious):.3f}"
    # The mask-located stand-off point is within 5 mm of the true one, and the flange got there (a few mm).
    obj = env.info()["object_xy"]
    np.testing.assert_allclose(obj, obj0, atol=1e-4)  # never touched
    true_target = obj + 0.09 * (HOME_XY - obj) / np.linalg.norm(HOME_XY - obj)
    assert np.linalg.norm(policy.targets[-1] - true_target) < 5e-3
    assert np.linalg.norm(out["ee_xy"][-1] - out["targets"][-1, :2]) < 3e-3
    assert abs(env.flange_pos()[2] - scene.home_flange_pos()[2]) < 5e-3
    env.close()


def _iou_with_analytic(env, mask):
    i = env.info()
    ana = mask_geometry.object_mask("box", env.params.size, i["object_xy"], i["object_yaw"], i["object_z"])
    return (ana & mask).sum() / (ana | mask).sum()


def test_sim_robot_home_and_validation():
    env = _sim_env()
    robot = SimRobot(env, home_ms=2500)
    robot.move_to(env.home_flange + np.array([0.06, 0.04, 0.0]))
    robot.wait_ms(300)
    assert np.linalg.norm(robot.flange_xy() - env.home_flange[:2]) > 0.01
    robot.home()
    assert np.linalg.norm(robot.flange_xy() - env.home_flange[:2]) < 5e-3
    with pytest.raises(ValueError, match="target"):
        robot.move_to(np.array([0.4, np.nan, 0.5]))
    with pytest.raises(ValueError, match="target"):
        robot.move_to(np.zeros(2))


def test_the_panda_py_robot_sketch_fits_the_robot_interface():
    """export/panda_py_robot.py imports without panda-py and has every method `Robot` asks for (it is
    never run here: there is no arm)."""
    import sys

    from mjx_push.export.panda_py_robot import PandaPyRobot

    assert isinstance(object.__new__(PandaPyRobot), Robot)
    assert "panda_py" not in sys.modules  # imported when a robot is made, not before
