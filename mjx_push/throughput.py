"""The throughput demo behind `mjx-push demo`: a batch of scenes stepped with random actions (substeps/s); writes
a PNG of object and goal masks. ("Demo" here is a show of the scene, not expert demonstrations.)"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push.batch import PushBatch
from mjx_push.env import EnvConfig
from mjx_push.errors import ConfigError


def run(config: EnvConfig, num_envs: int, steps: int, seed: int, out: Path, progress=None) -> dict:
    """Step `num_envs` environments for `steps` random actions; returns throughput figures."""
    if steps < 1:
        raise ConfigError(f"steps must be >= 1, got {steps}")
    out.mkdir(parents=True, exist_ok=True)
    batch = PushBatch(config, num_envs)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    state = jax.block_until_ready(batch.jit_reset(key))
    first = None
    substeps = 0
    t_run = None
    for i in range(steps):
        key, k = jax.random.split(key)
        actions = jax.random.uniform(k, (num_envs, 3), minval=-1.0, maxval=1.0)
        state = jax.block_until_ready(batch.jit_step(state, actions))
        n = int(jnp.sum(state.info["substeps"]))
        if i == 0:
            first = state
            t_run = time.perf_counter()
            compile_s = t_run - t0
        else:
            substeps += n
        if progress is not None:
            elapsed = time.perf_counter() - t_run
            progress(i + 1, steps, substeps / elapsed if i and elapsed > 0 else 0.0)
    run_s = time.perf_counter() - t_run
    _save_masks(first, batch, out / "masks.png")
    stats = {
        "num_envs": num_envs,
        "env_steps": steps,
        "compile_and_first_step_s": round(compile_s, 2),
        "substeps_per_s": round(substeps / run_s, 1) if steps > 1 else None,
        "invalid": int(jnp.sum(state.info["invalid_count"])),
        "success_final": float(jnp.mean(state.metrics["success"])),
        "masks_png": str(out / "masks.png"),
    }
    (out / "demo.json").write_text(json.dumps(stats, indent=2))
    return stats


def _save_masks(state, batch: PushBatch, path: Path, max_envs: int = 8) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    obj = np.asarray(state.obs["object_mask"])
    goal = np.asarray(state.obs["goal_mask"])
    shapes = [batch.geom_types[i] for i in np.asarray(batch.shape_ids)]
    n = min(len(obj), max_envs)
    fig, axes = plt.subplots(2, n, figsize=(1.6 * n, 3.4), squeeze=False)
    for j in range(n):
        for row, (img, name) in enumerate(((obj, "object"), (goal, "goal"))):
            ax = axes[row, j]
            ax.imshow(img[j], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(name)
        axes[0, j].set_title(f"env {j}: {shapes[j]}", fontsize=8)
    fig.suptitle("under-table camera masks (64x64), after the first step")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
