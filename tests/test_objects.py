"""Object randomisation (docs/task.md sections 1 and 4): ranges, shape filters, the improved mass sampler."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from mjx_push import objects, scene

HOME = jnp.asarray(scene.home_flange_pos()[:2], jnp.float32)
N = 4000


def draw(cfg, geom_type, n=N, seed=0):
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    p = jax.jit(jax.vmap(lambda k: objects.sample(k, cfg, geom_type, HOME)))(keys)
    return jax.tree.map(np.asarray, p)


def test_improved_mass_matches_formula_cdf():
    cfg = objects.ObjectConfig(mode="improved")
    m = np.asarray(jax.jit(lambda k: objects.sample_improved_mass(k, cfg, (20000,)))(jax.random.PRNGKey(1)))
    f_min, f_max = 0.001 * 0.2, 1.0 * 1.0
    a, b = (f_max - f_min) / 0.4, f_min / 0.4
    beta = 1 / 7

    def cdf(x):  # u = (m - b)/a; half the mass is x clipped, half is 1 - x
        u = np.clip((x - b) / a, 0, 1)
        return 0.5 * (1 - np.exp(-u / beta)) + 0.5 * np.exp(-(1 - u) / beta) * (u > 0)

    assert m.min() >= b - 1e-6 and m.max() <= a + b + 1e-6
    np.testing.assert_allclose([b, a + b], [0.0005, 2.5], rtol=1e-6)  # docs/task.md section 4: m in [0.0005, 2.5]
    assert stats.kstest(m, cdf).pvalue > 1e-3
    # The density piles up at both ends: each outer tenth holds 0.5 (1 - e^-0.7) = 25 % (uniform: 10 %).
    expected = 0.5 * (1 - np.exp(-0.1 / beta))
    assert abs(np.mean(m < b + 0.1 * a) - expected) < 0.02
    assert abs(np.mean(m > b + 0.9 * a) - expected) < 0.02


def test_improved_mode_fixes_friction():
    p = draw(objects.ObjectConfig(mode="improved"), "box", 500)
    np.testing.assert_allclose(p.friction[:, 0], 0.4)


def test_uniform_ranges_and_consistent_inertia():
    cfg = objects.ObjectConfig()
    p = draw(cfg, "box")
    length, width, height = 2 * p.size[:, 0], 2 * p.size[:, 1], 2 * p.size[:, 2]
    assert length.min() >= 0.05 and length.max() <= 0.11
    assert np.all(height >= 0.046 - 1e-7) and np.all(height <= np.minimum(0.08, np.minimum(length, width)) + 1e-7)
    assert stats.kstest(p.mass, stats.uniform(0.001, 0.999).cdf).pvalue > 1e-3
    assert stats.kstest(p.friction[:, 0], stats.uniform(0.2, 0.8).cdf).pvalue > 1e-3
    assert p.friction[:, 1].min() >= 0.001 and p.friction[:, 1].max() <= 0.01
    np.testing.assert_allclose(p.inertia[:, 2], p.mass / 12 * (length**2 + width**2), rtol=1e-5)
    c = draw(cfg, "cylinder")
    assert c.size[:, 0].min() >= 0.04 and c.size[:, 0].max() <= 0.055
    assert np.all(2 * c.size[:, 1] <= 0.055 + 1e-7)
    np.testing.assert_allclose(c.inertia[:, 2], c.mass * c.size[:, 0] ** 2 / 2, rtol=1e-5)


def test_start_and_goal_poses():
    p = draw(objects.ObjectConfig(), "box")
    home = np.asarray(HOME)
    off_s, off_g = p.start[:, :2] - home, p.goal[:, :2] - home
    assert np.abs(off_s).max() <= 0.1 + 1e-6 and np.abs(off_g).max() <= 0.1 + 1e-6
    assert np.linalg.norm(off_s, axis=1).min() >= 0.1 - 1e-6
    assert np.linalg.norm(off_g, axis=1).min() < 0.02  # goals have no minimum distance
    assert p.start[:, 2].min() >= -np.pi and p.start[:, 2].max() < np.pi


def test_shape_filters():
    sq = draw(objects.ObjectConfig(shape="square"), "box", 500)
    np.testing.assert_array_equal(sq.size[:, 0], sq.size[:, 1])
    rect = draw(objects.ObjectConfig(shape="rectangular"), "box", 2000)
    diff = np.abs(2 * rect.size[:, 0] - 2 * rect.size[:, 1])
    assert diff.min() >= 0.02 - 1e-6
    assert 2 * rect.size[:, :2].min() >= 0.05 - 1e-7 and 2 * rect.size[:, :2].max() <= 0.11 + 1e-7
    assert objects.ObjectConfig(shape="cylinder").shapes() == ("cylinder",)
    assert objects.ObjectConfig(shape="any").shapes() == ("box", "cylinder")
    with pytest.raises(ValueError, match="draws no 'cylinder'"):
        objects.sample(jax.random.PRNGKey(0), objects.ObjectConfig(shape="square"), "cylinder", HOME)


def test_difficult_case_min_height_wins():
    cfg = objects.ObjectConfig(mass=(0.001, 0.01), friction=(0.2, 0.3), min_height=0.052)
    p = draw(cfg, "box", 1000)
    assert np.all(2 * p.size[:, 2] >= 0.052 - 1e-7)
    assert p.mass.max() <= 0.01 and p.friction[:, 0].max() <= 0.3


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(mass=(1.0, 0.1)), "objects.mass"),
        (dict(friction=(0.0, 0.5)), "objects.friction"),
        (dict(shape="triangle"), "objects.shape"),
        (dict(mode="fancy"), "objects.mode"),
        (dict(radius=(0.05,)), "objects.radius"),
        (dict(shape="rectangular", side=(0.05, 0.06)), "objects.side"),
        (dict(min_height=0.1, max_height_cylinder=0.05), "objects.max_height"),
    ],
)
def test_invalid_config_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        objects.ObjectConfig(**kwargs)
