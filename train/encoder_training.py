"""Train the mask autoencoder (docs/task.md section 5) on masks generated on device, and report its
reconstruction quality on held-out masks (mean IoU of reconstructions thresholded at p = 0.5).

Every batch is fresh (masks are cheap to draw analytically), so there is no dataset to overfit; the
held-out set is drawn once from a key no training batch uses.

``yaw_weight`` > 0 adds an auxiliary loss (not in the paper): a linear head on the latent mean must
predict each cuboid's face orientation (cos 4 yaw, sin 4 yaw) and, for rectangular ones, the long
side's (cos 2 yaw, sin 2 yaw). The pixel loss alone leaves the orientation out of the 6 numbers
(`benchmarks/latent_precision.py`: probes do no better than chance), while the expert needs it to push
a cuboid from its face. The head is discarded; the saved encoder has the paper's architecture.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import jax
import jax.numpy as jnp
import optax

from mjx_push import encoder as enc
from mjx_push import objects
from mjx_push.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class EncoderTrainConfig:
    steps: int = 6000
    batch_size: int = 64
    lr: float = 1e-3
    kl_weight: float = 1.0  # weight of the KL penalty against the summed per-pixel cross-entropy
    yaw_weight: float = 0.0  # weight of the auxiliary cuboid-orientation loss (0: the paper's loss)
    eval_masks: int = 1000
    eval_every: int = 500
    seed: int = 0

    def __post_init__(self):
        for name in ("steps", "batch_size", "eval_masks", "eval_every"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v > 0):
                raise ConfigError(f"encoder.{name} must be a positive int, got {v!r}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ConfigError(f"encoder.lr must be a finite number > 0, got {self.lr}")
        if not (math.isfinite(self.kl_weight) and self.kl_weight >= 0):
            raise ConfigError(f"encoder.kl_weight must be a finite number >= 0, got {self.kl_weight}")
        if not (math.isfinite(self.yaw_weight) and self.yaw_weight >= 0):
            raise ConfigError(f"encoder.yaw_weight must be a finite number >= 0, got {self.yaw_weight}")


def loss_fn(params, x, key, kl_weight):
    """Summed per-pixel binary cross-entropy + kl_weight * KL(q(z|x) || N(0, I)), batch mean."""
    loss, aux, _ = _vae_loss(params, x, key, kl_weight)
    return loss, aux


def _vae_loss(params, x, key, kl_weight):
    logits, mean, logvar = enc.VAE().apply({"params": params}, x, key)
    bce = jnp.sum(optax.sigmoid_binary_cross_entropy(logits, x), axis=(-2, -1))
    kl = -0.5 * jnp.sum(1 + logvar - mean**2 - jnp.exp(logvar), axis=-1)
    return jnp.mean(bce + kl_weight * kl), {"bce": jnp.mean(bce), "kl": jnp.mean(kl)}, mean


def yaw_targets(is_box: jax.Array, yaw: jax.Array, box_size: jax.Array) -> tuple[jax.Array, jax.Array]:
    """[n, 4] targets (cos 4 yaw, sin 4 yaw, cos 2 yaw, sin 2 yaw) and [n, 4] weights: the face yaw of
    every cuboid, the long side's of those whose sides differ by at least objects.RECT_MIN_DIFF."""
    rect = is_box & (2.0 * jnp.abs(box_size[:, 0] - box_size[:, 1]) >= objects.RECT_MIN_DIFF)
    targets = jnp.stack([jnp.cos(4 * yaw), jnp.sin(4 * yaw), jnp.cos(2 * yaw), jnp.sin(2 * yaw)], -1)
    weights = jnp.stack([is_box, is_box, rect, rect], -1).astype(jnp.float32)
    return targets, weights


def init_yaw_head(key: jax.Array) -> dict:
    """The linear head (LeCun-normal kernel, zero bias): not zero, so the orientation loss reaches the
    encoder from the first step."""
    return {"kernel": jax.random.normal(key, (enc.LATENT_DIM, 4)) / jnp.sqrt(enc.LATENT_DIM), "bias": jnp.zeros(4)}


def yaw_loss(head: dict, mean: jax.Array, is_box: jax.Array, yaw: jax.Array, box_size: jax.Array) -> jax.Array:
    """Squared error of the linear head's orientation prediction from the latent mean, per cuboid."""
    targets, weights = yaw_targets(is_box, yaw, box_size)
    err = weights * (mean @ head["kernel"] + head["bias"] - targets) ** 2
    return jnp.sum(err) / jnp.maximum(jnp.sum(weights[:, 0]), 1.0)


def make_step(cfg: EncoderTrainConfig, optimizer):
    """One Adam step; with yaw_weight > 0 the trained state is {"vae": params, "yaw_head": head}."""
    if cfg.yaw_weight > 0:

        def loss_with_yaw(state, x, key, pose):
            vae_loss, aux, mean = _vae_loss(state["vae"], x, key, cfg.kl_weight)
            y = yaw_loss(state["yaw_head"], mean, *pose)
            return vae_loss + cfg.yaw_weight * y, {**aux, "yaw": y}

    def step(params, opt_state, key):
        k_data, k_noise = jax.random.split(key)
        if cfg.yaw_weight > 0:
            masks, *pose = enc.random_masks_with_pose(k_data, cfg.batch_size)
            (loss, aux), grads = jax.value_and_grad(loss_with_yaw, has_aux=True)(
                params, masks.astype(jnp.float32), k_noise, pose
            )
        else:
            x = enc.random_masks(k_data, cfg.batch_size).astype(jnp.float32)
            (loss, aux), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, x, k_noise, cfg.kl_weight)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, {"loss": loss, **aux}

    return step


def evaluate(params, held_out: jax.Array) -> dict:
    """Mean / 5th-percentile IoU of thresholded reconstructions of `held_out` masks [n, 64, 64] bool."""
    logits = enc.VAE().apply({"params": params}, held_out.astype(jnp.float32), method=enc.VAE.reconstruct)
    ious = enc.iou(logits > 0, held_out)
    return {
        "iou_mean": float(jnp.mean(ious)),
        "iou_p05": float(jnp.percentile(ious, 5)),
        "iou_min": float(jnp.min(ious)),
    }


def train_encoder(cfg: EncoderTrainConfig, progress: Callable[[int, dict], None] | None = None):
    """-> (VAE params, report). `progress(step, metrics)` is called at every evaluation."""
    key = jax.random.PRNGKey(cfg.seed)
    k_init, k_eval, k_train = jax.random.split(key, 3)
    params = enc.init_vae(k_init)
    if cfg.yaw_weight > 0:  # the auxiliary head trains beside the VAE and is dropped at the end
        params = {"vae": params, "yaw_head": init_yaw_head(jax.random.fold_in(k_init, 1))}
    vae = (lambda p: p["vae"]) if cfg.yaw_weight > 0 else (lambda p: p)  # noqa: E731
    schedule = optax.cosine_decay_schedule(cfg.lr, cfg.steps, alpha=0.05)
    optimizer = optax.adam(schedule)
    opt_state = optimizer.init(params)
    held_out = jax.jit(enc.random_masks, static_argnums=1)(k_eval, cfg.eval_masks)
    step = jax.jit(make_step(cfg, optimizer), donate_argnums=(0, 1))
    eval_fn = jax.jit(
        lambda p: enc.iou(
            enc.VAE().apply({"params": p}, held_out.astype(jnp.float32), method=enc.VAE.reconstruct) > 0, held_out
        )
    )
    t0 = time.perf_counter()
    curve = []
    for i in range(cfg.steps):
        params, opt_state, m = step(params, opt_state, jax.random.fold_in(k_train, i))
        if (i + 1) % cfg.eval_every == 0 or i + 1 == cfg.steps:
            ious = eval_fn(vae(params))
            row = {
                "step": i + 1,
                "loss": float(m["loss"]),
                "bce": float(m["bce"]),
                "kl": float(m["kl"]),
                "heldout_iou": float(jnp.mean(ious)),
                "seconds": time.perf_counter() - t0,
            }
            if "yaw" in m:
                row["yaw_loss"] = float(m["yaw"])
            curve.append(row)
            if progress is not None:
                progress(i + 1, row)
    params = vae(params)
    report = {
        **evaluate(params, held_out),
        "heldout_masks": cfg.eval_masks,
        "curve": curve,
        "train_seconds": time.perf_counter() - t0,
        "config": dataclasses.asdict(cfg),
    }
    return params, report
