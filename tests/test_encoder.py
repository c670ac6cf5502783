"""The mask autoencoder (mjx_push/encoder.py), its trainer (train/encoder_training.py) and the shipped weights."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push import encoder as enc
from mjx_push import scene
from mjx_push.train.encoder_training import EncoderTrainConfig, loss_fn


@pytest.fixture(scope="module")
def held_out():
    return jax.jit(enc.random_masks, static_argnums=1)(jax.random.PRNGKey(77), 256)


def test_architecture_matches_the_spec():
    params = enc.init_vae(jax.random.PRNGKey(0))
    e = params["encoder"]
    assert [e[f"Conv_{i}"]["kernel"].shape for i in range(4)] == [
        (4, 4, 1, 32),
        (4, 4, 32, 64),
        (4, 4, 64, 128),
        (4, 4, 128, 256),
    ]
    assert e["Dense_0"]["kernel"].shape == (2 * 2 * 256, 256)
    assert e["mean"]["kernel"].shape == (256, 6) and e["logvar"]["kernel"].shape == (256, 6)
    x = jnp.zeros((3, 64, 64))
    logits, mean, logvar = enc.VAE().apply({"params": params}, x, jax.random.PRNGKey(1))
    assert logits.shape == (3, 64, 64) and mean.shape == (3, 6)
    assert enc.encode(e, x[0]).shape == (6,)  # any leading shape


def test_upconv_is_a_stride_two_transposed_convolution():
    """UpConv maps a single active input pixel to a k x k footprint at twice its position, like
    nn.ConvTranspose(kernel k, stride 2, VALID): output 2H + k - 2."""
    for k, h in ((4, 2), (4, 6), (6, 30)):
        m = enc.UpConv(3, k)
        x = jnp.zeros((1, h, h, 2)).at[0, 1, 1, 0].set(1.0)
        p = m.init(jax.random.PRNGKey(0), x)
        p = jax.tree.map(lambda a: jnp.ones_like(a) if a.ndim > 1 else jnp.zeros_like(a), p)
        y = m.apply(p, x)
        assert y.shape == (1, 2 * h + k - 2, 2 * h + k - 2, 3)
        footprint = np.argwhere(np.asarray(y[0, :, :, 0]) != 0)
        assert footprint.min(0).tolist() == [2, 2] and footprint.max(0).tolist() == [2 + k - 1, 2 + k - 1]


def test_random_masks_cover_the_training_distribution(held_out):
    m = np.asarray(held_out)
    area = m.sum(axis=(1, 2))
    assert m.dtype == bool and (area > 10).all()  # every object is in view
    assert area.std() > 5  # sizes and heights vary
    cols = np.array([np.nonzero(x.any(axis=0))[0].mean() for x in m])
    rows = np.array([np.nonzero(x.any(axis=1))[0].mean() for x in m])
    assert np.ptp(cols) > 40 and np.ptp(rows) > 40  # positions span most of the image


def test_training_reduces_the_loss():
    cfg = EncoderTrainConfig(steps=8, batch_size=8)
    params = enc.init_vae(jax.random.PRNGKey(0))
    x = enc.random_masks(jax.random.PRNGKey(1), 8).astype(jnp.float32)
    import optax

    opt = optax.adam(1e-3)
    state = opt.init(params)
    grad = jax.jit(jax.value_and_grad(lambda p, k: loss_fn(p, x, k, cfg.kl_weight)[0]))
    first = None
    for i in range(8):
        loss, g = grad(params, jax.random.PRNGKey(i))
        first = first if first is not None else float(loss)
        updates, state = opt.update(g, state, params)
        params = optax.apply_updates(params, updates)
    assert float(loss) < 0.5 * first


def test_bad_encoder_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        enc.load(tmp_path / "none.msgpack")
    bad = tmp_path / "bad.msgpack"
    bad.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ValueError, match="corrupt|structure|do not match"):
        enc.load(bad)
    params = enc.init_vae(jax.random.PRNGKey(0))["encoder"]
    params = {**params, "mean": {"kernel": jnp.zeros((256, 4)), "bias": jnp.zeros(4)}}
    enc.save(tmp_path / "wrong.msgpack", params, {})
    with pytest.raises(ValueError, match="wrong shapes"):
        enc.load(tmp_path / "wrong.msgpack")


def test_bad_training_settings_are_named():
    with pytest.raises(ValueError, match="encoder.steps"):
        EncoderTrainConfig(steps=0)
    with pytest.raises(ValueError, match="encoder.kl_weight"):
        EncoderTrainConfig(kl_weight=-1.0)
    with pytest.raises(ValueError, match="encoder.yaw_weight must be a finite number >= 0"):
        EncoderTrainConfig(yaw_weight=-0.5)


def test_yaw_targets_and_loss():
    """The auxiliary orientation loss: face yaw (4 yaw) for every cuboid, the long side (2 yaw) only for
    rectangular ones, nothing for cylinders; zero for a head that predicts the targets."""
    from mjx_push.train.encoder_training import yaw_loss, yaw_targets

    is_box = jnp.array([True, True, False])
    yaw = jnp.array([jnp.pi / 8, jnp.pi / 4, 0.3])
    size = jnp.array([[0.03, 0.03, 0.02], [0.05, 0.025, 0.02], [0.04, 0.02, 0.0]])  # square, rectangle, -
    t, w = yaw_targets(is_box, yaw, size)
    np.testing.assert_allclose(t[0, :2], [0.0, 1.0], atol=1e-6)  # cos, sin of 4 * pi / 8
    np.testing.assert_allclose(t[1], [-1.0, 0.0, 0.0, 1.0], atol=1e-6)
    np.testing.assert_array_equal(w, [[1, 1, 0, 0], [1, 1, 1, 1], [0, 0, 0, 0]])
    head = {"kernel": jnp.eye(6, 4), "bias": jnp.zeros(4)}
    mean = jnp.concatenate([t, jnp.zeros((3, 2))], axis=1)
    assert float(yaw_loss(head, mean, is_box, yaw, size)) == pytest.approx(0.0, abs=1e-9)
    off = mean.at[2].set(5.0)  # the cylinder's latent is not scored
    assert float(yaw_loss(head, off, is_box, yaw, size)) == pytest.approx(0.0, abs=1e-9)
    # Off by 1 on one cuboid's 4 weighted outputs: error 4 over 2 cuboids.
    assert float(yaw_loss(head, mean.at[1, :4].add(1.0), is_box, yaw, size)) == pytest.approx(2.0)


def test_masks_with_their_pose_are_the_training_masks():
    key = jax.random.PRNGKey(3)
    masks, is_box, yaw, size = enc.random_masks_with_pose(key, 6)
    np.testing.assert_array_equal(masks, enc.random_masks(key, 6))
    assert masks.shape == (6, 64, 64) and is_box.shape == yaw.shape == (6,) and size.shape == (6, 3)


def test_yaw_weight_trains_the_encoder_through_the_head():
    """With yaw_weight > 0 a step updates {"vae", "yaw_head"}, and the orientation loss reaches the
    encoder's mean path (its gradient there differs from the pixel loss alone)."""
    import optax

    from mjx_push.train.encoder_training import init_yaw_head, make_step

    cfg = EncoderTrainConfig(steps=1, batch_size=4, yaw_weight=10.0)
    state = {"vae": enc.init_vae(jax.random.PRNGKey(0)), "yaw_head": init_yaw_head(jax.random.PRNGKey(1))}
    opt = optax.sgd(1e-3)
    new, _, metrics = jax.jit(make_step(cfg, opt))(state, opt.init(state), jax.random.PRNGKey(5))
    assert float(metrics["yaw"]) > 0
    assert not np.allclose(new["yaw_head"]["kernel"], state["yaw_head"]["kernel"])
    moved = new["vae"]["encoder"]["mean"]["kernel"] - state["vae"]["encoder"]["mean"]["kernel"]
    plain = EncoderTrainConfig(steps=1, batch_size=4)
    new_plain, _, _ = jax.jit(make_step(plain, opt))(state["vae"], opt.init(state["vae"]), jax.random.PRNGKey(5))
    moved_plain = new_plain["encoder"]["mean"]["kernel"] - state["vae"]["encoder"]["mean"]["kernel"]
    assert not np.allclose(moved, moved_plain)


def test_the_shipped_encoder_is_recorded_and_reads_the_object_pose(held_out):
    """The pretrained encoder ships with the command and seed that made it and its held-out IoU, and
    its 6 latents order objects by where they are: latent distance ranks pairs of masks like the
    distance between their silhouettes' centroids (Spearman 0.73 measured; an untrained encoder ~0)."""
    from scipy.stats import spearmanr

    record = enc.load_record()
    assert record["command"].startswith("mjx-push train-encoder") and isinstance(record["seed"], int)
    assert record["iou_mean"] > 0.85
    z = np.asarray(enc.encode(enc.load(), held_out), np.float64)
    m = np.asarray(held_out)
    rows, cols = np.indices((scene.IMAGE_SIZE, scene.IMAGE_SIZE))
    area = m.sum(axis=(1, 2))
    centroid = np.stack([(m * rows).sum(axis=(1, 2)) / area, (m * cols).sum(axis=(1, 2)) / area], axis=1)
    i, j = np.triu_indices(len(z), 1)
    rho = spearmanr(np.linalg.norm(z[i] - z[j], axis=1), np.linalg.norm(centroid[i] - centroid[j], axis=1))
    assert rho.correlation > 0.6, rho.correlation
