"""Vision encoder of the object masks (docs/task.md section 5): a variational autoencoder whose mean is the
6-number latent the agents observe.

Encoder: 4 convolutions (kernel 4, stride 2, no padding; 32, 64, 128, 256 channels, ReLU) take the
64x64 mask to 2x2x256, a 256-unit dense layer, then a 6-unit mean head and a log-variance head (used
only by the KL penalty while training). Decoder: the mirror image; its last transposed convolution
has kernel 6 so that 30 -> 64 pixels (kernel 4 would give 62).

The package ships a pretrained encoder (`assets/encoder.msgpack`, made by `mjx-push train-encoder`;
`assets/encoder.json` records the command, seed and held-out IoU). Agents call `encode` once per
environment step, so the replay buffer stores latents, never images.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import serialization

from mjx_push import masks, objects, scene
from mjx_push.errors import ConfigError

LATENT_DIM = 6
CHANNELS = (32, 64, 128, 256)
DENSE = 256
ASSET_DIR = Path(str(resources.files("mjx_push") / "assets"))
PRETRAINED = ASSET_DIR / "encoder.msgpack"
PRETRAINED_RECORD = ASSET_DIR / "encoder.json"


class Encoder(nn.Module):
    @nn.compact
    def __call__(self, x):  # x [..., 64, 64] in {0, 1}
        lead = x.shape[:-2]
        h = x.reshape((-1, scene.IMAGE_SIZE, scene.IMAGE_SIZE, 1)).astype(jnp.float32)
        for c in CHANNELS:
            h = nn.relu(nn.Conv(c, (4, 4), strides=(2, 2), padding="VALID")(h))
        h = nn.relu(nn.Dense(DENSE)(h.reshape((h.shape[0], -1))))
        mean = nn.Dense(LATENT_DIM, name="mean")(h)
        logvar = nn.Dense(LATENT_DIM, name="logvar")(h)
        return mean.reshape(lead + (LATENT_DIM,)), logvar.reshape(lead + (LATENT_DIM,))


class UpConv(nn.Module):
    """Transposed convolution (stride 2, kernel k even, no padding: H -> 2H + k - 2) computed as a
    stride-1 convolution with kernel k/2 producing the four output phases, then depth-to-space. The
    two are the same family of functions; this form's gradient is several times faster on XLA's CPU
    backend than the dilated convolution behind nn.ConvTranspose."""

    features: int
    kernel: int = 4

    @nn.compact
    def __call__(self, x):
        p = self.kernel // 2 - 1
        x = jnp.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))
        y = nn.Conv(4 * self.features, (self.kernel // 2,) * 2, padding="VALID")(x)
        b, h, w, _ = y.shape
        y = y.reshape(b, h, w, 2, 2, self.features).transpose(0, 1, 3, 2, 4, 5)
        return y.reshape(b, 2 * h, 2 * w, self.features)


class Decoder(nn.Module):
    @nn.compact
    def __call__(self, z):  # z [..., 6] -> logits [..., 64, 64]
        lead = z.shape[:-1]
        h = nn.relu(nn.Dense(DENSE)(z.reshape((-1, LATENT_DIM))))
        h = nn.relu(nn.Dense(2 * 2 * CHANNELS[-1])(h)).reshape((-1, 2, 2, CHANNELS[-1]))
        for c in CHANNELS[-2::-1]:  # 2 -> 6 -> 14 -> 30
            h = nn.relu(UpConv(c, 4)(h))
        h = UpConv(1, 6)(h)  # 30 -> 64
        return h[..., 0].reshape(lead + (scene.IMAGE_SIZE, scene.IMAGE_SIZE))


class VAE(nn.Module):
    def setup(self):
        self.encoder = Encoder()
        self.decoder = Decoder()

    def __call__(self, x, key):
        mean, logvar = self.encoder(x)
        z = mean + jnp.exp(0.5 * logvar) * jax.random.normal(key, mean.shape)
        return self.decoder(z), mean, logvar

    def reconstruct(self, x):
        """Deterministic reconstruction (decoder of the mean): logits."""
        return self.decoder(self.encoder(x)[0])


def encode(encoder_params, mask: jax.Array) -> jax.Array:
    """Latent means [..., 6] of masks [..., 64, 64] (bool or float)."""
    return Encoder().apply({"params": encoder_params}, mask)[0]


def init_vae(key: jax.Array):
    return VAE().init(key, jnp.zeros((1, scene.IMAGE_SIZE, scene.IMAGE_SIZE)), key)["params"]


def random_masks(key: jax.Array, n: int, x_range=(-0.25, 0.30), y_range=(-0.30, 0.30)) -> jax.Array:
    """`n` masks [n, 64, 64] of objects with random shape (half boxes, half cylinders), size and height
    from Table I, yaw in [-pi, pi) and position EE_home + (x, y) from the given ranges (docs/task.md section 5)."""
    return random_masks_with_pose(key, n, x_range, y_range)[0]


def random_masks_with_pose(key: jax.Array, n: int, x_range=(-0.25, 0.30), y_range=(-0.30, 0.30)):
    """`random_masks`' masks and what drew them: (masks [n, 64, 64], is_box [n], yaw [n], box half
    extents [n, 3]; the last meaningful where is_box)."""
    cfg = objects.ObjectConfig()
    home = jnp.asarray(scene.home_flange_pos()[:2], jnp.float32)
    k_shape, k_pose, k_box, k_cyl = jax.random.split(key, 4)
    is_box = jax.random.bernoulli(k_shape, 0.5, (n,))
    lo = jnp.array([x_range[0], y_range[0], -jnp.pi])
    hi = jnp.array([x_range[1], y_range[1], jnp.pi])
    pose = jax.random.uniform(k_pose, (n, 3), minval=lo, maxval=hi)
    xy = home + pose[:, :2]

    def one(geom_type, k, xy, yaw):
        size = objects.sample(k, cfg, geom_type, home).size
        hh = size[2] if geom_type == "box" else size[1]
        return masks.object_mask(geom_type, size, xy, yaw, scene.TABLE_TOP + hh)

    box_keys = jax.random.split(k_box, n)
    boxes = jax.vmap(lambda k, p, y: one("box", k, p, y))(box_keys, xy, pose[:, 2])
    cyls = jax.vmap(lambda k, p, y: one("cylinder", k, p, y))(jax.random.split(k_cyl, n), xy, pose[:, 2])
    box_size = jax.vmap(lambda k: objects.sample(k, cfg, "box", home).size)(box_keys)
    return jnp.where(is_box[:, None, None], boxes, cyls), is_box, pose[:, 2], box_size


def iou(pred: jax.Array, target: jax.Array) -> jax.Array:
    """Per-mask intersection over union of boolean masks [..., 64, 64] (1 where both are empty)."""
    inter = jnp.sum(pred & target, axis=(-2, -1))
    union = jnp.sum(pred | target, axis=(-2, -1))
    return jnp.where(union > 0, inter / jnp.maximum(union, 1), 1.0)


# --- saving and loading ------------------------------------------------------------------------------
def save(path: Path, encoder_params, record: dict) -> None:
    """Write encoder params (msgpack) and a JSON record (command, seed, metrics) next to them."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(serialization.msgpack_serialize(jax.tree.map(lambda a: jax.device_get(a), encoder_params)))
    path.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")


def _template():
    return jax.eval_shape(lambda: Encoder().init(jax.random.PRNGKey(0), jnp.zeros((1, 64, 64)))["params"])


def load(path: Path | None = None):
    """Encoder params from `path` (default: the shipped pretrained encoder). A missing, corrupt or
    differently shaped file raises ValueError naming the file and the problem."""
    path = Path(path) if path is not None else PRETRAINED
    if not path.is_file():
        raise ConfigError(f"encoder weights not found: {path} (train them with `mjx-push train-encoder`)")
    try:
        raw = serialization.msgpack_restore(path.read_bytes())
    except Exception as e:  # msgpack raises several unrelated types on garbage
        raise ConfigError(f"encoder weights {path} are corrupt or not a msgpack file: {e}") from None
    template = _template()
    want = {
        "/".join(str(getattr(k, "key", k)) for k in p): v.shape
        for p, v in jax.tree_util.tree_leaves_with_path(template)
    }
    try:
        got = {
            "/".join(str(getattr(k, "key", k)) for k in p): v.shape for p, v in jax.tree_util.tree_leaves_with_path(raw)
        }
    except Exception as e:
        raise ConfigError(f"encoder weights {path} have an unexpected structure: {e}") from None
    if got != want:
        missing = sorted(set(want) - set(got))
        wrong = sorted(k for k in set(want) & set(got) if want[k] != got[k])
        raise ConfigError(
            f"encoder weights {path} do not match the encoder architecture: "
            f"missing {missing[:4]}, wrong shapes {[(k, got[k], want[k]) for k in wrong[:4]]}, "
            f"unexpected {sorted(set(got) - set(want))[:4]}"
        )
    return jax.tree.map(jnp.asarray, raw)


def load_record(path: Path | None = None) -> dict:
    path = Path(path) if path is not None else PRETRAINED
    rec = path.with_suffix(".json")
    return json.loads(rec.read_text()) if rec.is_file() else {}
