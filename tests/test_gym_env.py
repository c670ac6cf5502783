"""The Gymnasium environment "MjxPush-v0" (mjx_push.export.gym_env) and Stable-Baselines3 on it: registration,
Gymnasium's and SB3's checkers through `gymnasium.make` (on a headless machine too), goals and rewards,
and SB3's hindsight relabelling with its default settings checked against the simulator's ground truth."""

import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mjx_push.export  # noqa: F401  (registers MjxPush-v0)
from mjx_push.export.cpu_env import CpuPushEnv
from tests.helpers import renderer_or_skip
from mjx_push.export.gym_env import MjxPushGymEnv, split_observation
from mjx_push import scene
from mjx_push.env import EnvConfig

REPO = Path(__file__).resolve().parents[1]
try:
    import stable_baselines3  # noqa: F401

    HAVE_SB3 = True
except ImportError:
    HAVE_SB3 = False
needs_sb3 = pytest.mark.skipif(not HAVE_SB3, reason="needs Stable-Baselines3: pip install -e '.[sb3]'")


@pytest.fixture(scope="module")
def env():
    e = gymnasium.make("MjxPush-v0", mask_source="analytic")
    yield e
    e.close()


def test_make_returns_the_environment_and_both_checkers_pass(env):
    # No Gymnasium wrapper in between: compute_reward is callable on what make returns (SB3's checker does).
    assert isinstance(env, MjxPushGymEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Gymnasium's checker reports problems as warnings: fail on any
        check_env(env, skip_render_check=True)
    if HAVE_SB3:
        from stable_baselines3.common.env_checker import check_env as sb3_check_env

        sb3_check_env(env)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert obs["observation"].shape == (8,) and obs["achieved_goal"].shape == obs["desired_goal"].shape == (2,)
    np.testing.assert_allclose(obs["observation"][:2], info["ee_xy_true"], atol=1e-3)
    np.testing.assert_array_equal(obs["achieved_goal"], np.float32(info["object_xy"]))
    np.testing.assert_array_equal(obs["desired_goal"], np.float32(info["goal_xy"]))
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert reward == env.compute_reward(obs["achieved_goal"], obs["desired_goal"], None)
    assert terminated is False and info["is_success"] == (reward == 0.0)


def test_reward_is_a_function_of_the_goals_alone(env):
    tau = env.config.success_tau
    goal = np.array([0.5, 0.0], np.float32)
    achieved = goal + np.array([[0.0, 0.0], [0.9 * tau, 0.0], [0.0, 1.1 * tau], [0.3, 0.3]], np.float32)
    expect = np.array([0.0, 0.0, -1.0, -1.0], np.float32)
    for info in (None, [{}] * 4, np.array([{} for _ in range(4)], dtype=object)):  # what SB3's HER passes
        r = env.compute_reward(achieved, np.tile(goal, (4, 1)), info)
        assert r.shape == (4,) and r.dtype == np.float32
        np.testing.assert_array_equal(r, expect)
    r2 = env.compute_reward(achieved.reshape(2, 2, 2), goal, None)  # any leading shape, broadcast goals
    np.testing.assert_array_equal(r2, expect.reshape(2, 2))
    assert env.compute_reward(achieved[1], goal, {}) == 0.0
    with pytest.raises(ValueError, match="xy positions"):
        env.compute_reward(np.zeros((4, 4096)), np.zeros((4, 4096)), None)  # the old mask goals


def test_mask_observation_and_action_checks():
    sim = CpuPushEnv(geom_type="box", mask_source="analytic")
    env = MjxPushGymEnv(geom_type="box", mask_source="analytic", observation="mask")
    obs, info = env.reset(seed=4)
    ee, mask = split_observation(obs["observation"])
    sim.reset(seed=0, params=env.sim.params, geom_type="box")
    np.testing.assert_array_equal(mask, sim.object_mask())
    np.testing.assert_allclose(ee, info["ee_xy_true"], atol=1e-3)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(4, np.float32))
    # A decoded substep count passed as a_s is clipped to 1, loudly: NumpyPolicy.act is not act_raw.
    a_s = float(env.config.substeps[1])
    with pytest.warns(UserWarning, match="not a substep count"):
        env.step(np.array([0.0, 0.0, a_s], np.float32))
    with pytest.raises(ValueError, match="observation must be one of"):
        MjxPushGymEnv(observation="pixels")


def test_headless_make_renders_and_passes_the_checkers():
    """A fresh process on a machine without a display, MUJOCO_GL unset: `gymnasium.make("export:MjxPush-v0")`
    (the module prefix imports and registers the package) picks EGL and renders the camera's masks."""
    renderer_or_skip()
    code = (
        "import sys, gymnasium, numpy as np\n"
        "from gymnasium.utils.env_checker import check_env\n"
        "env = gymnasium.make('export:MjxPush-v0', render_mode='rgb_array', render_size=(48, 64))\n"
        "assert env.unwrapped.mask_source == 'render', env.unwrapped.mask_source\n"
        "check_env(env)\n"
        f"if {HAVE_SB3}:\n"
        "    from stable_baselines3.common.env_checker import check_env as sb3_check_env\n"
        "    sb3_check_env(env)\n"
        "env.reset(seed=0)\n"
        "assert env.render().shape == (48, 64, 3)\n"
        "print('ok', env.unwrapped.mask_source)\n"
    )
    clean = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MUJOCO_GL", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=clean, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "ok render" in r.stdout, r.stdout[-2000:] + r.stderr[-4000:]


class _GroundTruth(gymnasium.Wrapper):
    """Logs the simulator's true object and goal positions (float64) of every step, independently of
    what the observations carry."""

    def __init__(self, env):
        super().__init__(env)
        self.episodes: list[dict] = []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.episodes.append(
            {"goal": np.array(info["goal_xy"], np.float64), "positions": [np.array(info["object_xy"], np.float64)]}
        )
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.episodes[-1]["positions"].append(np.array(info["object_xy"], np.float64))
        return obs, reward, terminated, truncated, info


@needs_sb3
def test_sb3_her_relabelled_rewards_match_the_ground_truth():
    """SB3's SAC with HerReplayBuffer at its default settings (future strategy, 4 sampled goals, no info
    copied): every sampled reward, relabelled or not, equals the task's reward for the true object
    position after the step and the goal the sample carries, which is either the episode's true goal
    or the object's true position at a later step of the same episode."""
    import torch
    from stable_baselines3 import SAC, HerReplayBuffer

    torch.set_num_threads(1)
    cfg = EnvConfig()
    tau = cfg.success_tau
    logged = _GroundTruth(MjxPushGymEnv(cfg, mask_source="analytic"))
    T = cfg.episode_length
    model = SAC(
        "MultiInputPolicy",
        logged,
        replay_buffer_class=HerReplayBuffer,
        buffer_size=4 * T,
        learning_starts=10**6,
        seed=0,
    )  # random actions only: no gradient step is needed here
    assert (model.replay_buffer.n_sampled_goal, model.replay_buffer.copy_info_dict) == (4, False)
    model.learn(total_timesteps=3 * T)
    s = model.replay_buffer.sample(1024)
    next_ag = s.next_observations["achieved_goal"].numpy()
    goal = s.observations["desired_goal"].numpy()
    rewards = s.rewards.numpy().ravel()

    episodes = logged.episodes[:3]
    relabelled, motion = 0, 0
    for j in range(len(rewards)):
        # The step this sample ends at: the object's true position equals the next achieved goal.
        hits = [
            (e, t)
            for e, ep in enumerate(episodes)
            for t in range(1, T + 1)
            if np.array_equal(ep["positions"][t].astype(np.float32), next_ag[j])
        ]
        assert hits, f"sample {j}: next achieved goal {next_ag[j]} is no true object position"
        e, t = hits[0]
        ep = episodes[e]
        if np.array_equal(ep["goal"].astype(np.float32), goal[j]):
            true_goal = ep["goal"]
        else:  # relabelled: the object's position at this or a later step of the episode
            later = [p for p in ep["positions"][t:] if np.array_equal(p.astype(np.float32), goal[j])]
            assert later, f"sample {j}: goal {goal[j]} is neither the episode's goal nor a later object position"
            true_goal, relabelled = later[0], relabelled + 1
            motion += np.linalg.norm(ep["positions"][t] - true_goal) >= tau
        expect = -1.0 + float(np.linalg.norm(ep["positions"][t] - true_goal) < tau)
        assert rewards[j] == expect, (j, rewards[j], expect)
    assert 0.7 < relabelled / len(rewards) < 0.9  # 4 of every 5 samples relabelled
    assert (rewards == 0).any() and (rewards == -1).any()
    assert motion > 0, "the random actions never moved an object: relabelled rewards were all 0"


def test_table_footprint_bounds_the_goals(env):
    space = env.observation_space["achieved_goal"]
    np.testing.assert_allclose(space.low, [scene.TABLE_X[0], scene.TABLE_Y[0]])
    np.testing.assert_allclose(space.high, [scene.TABLE_X[1], scene.TABLE_Y[1]])
