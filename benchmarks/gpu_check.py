"""The device check: environment and training throughput, compile times and a short learning run, in one
JSON. Run it through `benchmarks/gpu_check.sh` on a GPU machine; `--tiny` runs the same stages at toy
sizes on a CPU (CI does, so the script cannot rot between device sessions).

    python -m benchmarks.gpu_check [--tiny] [--sizes 2048 8192 4096 1024] [--preset paper]
                                   [--learn-seconds 150] [--budget-s 420] [--out outputs/gpu_check.json]

Stages, in order of what users need first, each skipped (and marked so) once the time budget is spent:
1. `env`, first size (the paper preset's 2,048 environments): the preset's environment
   (`mjx_push.batch.PushBatch`) driven by the substep scheduler of the training rollout with uniform
   random actions for `--env-steps` steps: compile seconds, useful substeps/s, env steps/s.
2. `train`: the preset's learner (VPM) through `mjx_push.train.loop.Runner`: the first batch's seconds
   (compilation included), then batches until `--learn-seconds` have passed: env steps/s and
   gradient updates/s, rollout and update seconds per batch.
3. `learn`: the same run's actor evaluated (deterministic, the preset's evaluation episodes, the shared
   rollout): success within 1, 2 and 5 cm and the final object-goal distance, with the env steps it
   trained on.
4. `env`, the other sizes, in the order given.
`machine` records the interpreter, the devices and the version and location of every package the check
imports. The JSON is rewritten after every measurement (each size, the first batch, each stage), and an
interrupt (SIGINT: `gpu_check.sh` sends one at its timeout) writes what was measured and why it stopped.
"""

from __future__ import annotations

import argparse
import json
import importlib.metadata as md
import importlib.util
import os
import platform
import sys
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import numpy as np

from benchmarks.sim_speed import measure_mjx
from mjx_push import encoder as enc
from mjx_push.train import presets
from mjx_push.train.loop import Runner, make_train
from mjx_push.train.push_task import make_push_adapter

TINY = dict(sizes=[4, 8], preset="smoke", learn_seconds=1.0, env_steps=3, budget_s=1800.0)
FULL = dict(sizes=[2048, 8192, 4096, 1024], preset="paper", learn_seconds=150.0, env_steps=10, budget_s=420.0)


# Distributions whose versions decide what ran: the image's (JAX and its CUDA plugin, flax, ...) and the
# ones carried as wheels (MuJoCo, MJX, brax, ...).
PACKAGES = (
    "jax",
    "jaxlib",
    "jax-cuda13-plugin",
    "jax-cuda13-pjrt",
    "jax-cuda12-plugin",
    "jax-cuda12-pjrt",
    "mujoco",
    "mujoco-mjx",
    "brax",
    "flax",
    "optax",
    "orbax-checkpoint",
    "numpy",
    "ml-dtypes",
    "scipy",
    "gymnasium",
    "tyro",
    "rich",
    "tensorboardX",
    "mjx-push",
)
MODULES = ("jax", "jaxlib", "mujoco", "brax", "flax", "optax", "orbax.checkpoint", "numpy", "mjx_push", "train")


def versions() -> tuple[dict, dict]:
    """Installed version of each distribution of PACKAGES (None: absent) and the folder each module of
    MODULES is imported from (the image's site-packages, a carried --target folder or the checkout)."""
    vers = {}
    for name in PACKAGES:
        try:
            vers[name] = md.version(name)
        except md.PackageNotFoundError:
            vers[name] = None
    where = {}
    for mod in MODULES:
        spec = importlib.util.find_spec(mod)
        where[mod] = str(Path(spec.origin).parent.parent) if spec and spec.origin else None
    return vers, where


def machine() -> dict:
    dev = jax.devices()[0]
    vers, where = versions()
    return {
        "backend": jax.default_backend(),
        "device": str(dev),
        "device_kind": dev.device_kind,
        "devices": len(jax.devices()),
        "host": f"{platform.machine()}, {os.cpu_count()} cores",
        "jax": jax.__version__,
        "python": platform.python_version(),
        "interpreter": sys.executable,
        "pythonpath": os.environ.get("PYTHONPATH", ""),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "packages": vers,
        "imported_from": where,
    }


def env_stage(cfg, sizes: list[int], steps: int, deadline: float, rows: list[dict], save) -> None:
    """Append one row per size to `rows`, calling `save()` after each."""
    for n in sizes:
        if time.perf_counter() > deadline:
            rows.append({"num_envs": n, "skipped": "time budget spent"})
            save()
            continue
        (r,) = measure_mjx(cfg.env, n, steps, 50, None, jax.random.PRNGKey(n), modes=("scheduled",))
        rows.append(
            {
                "num_envs": n,
                "devices": r["devices"],
                "compile_s": r["compile_s"],
                "useful_substeps_per_s": r["useful_substeps_per_s"],
                "env_steps_per_s": r["env_steps_per_s"],
                "wall_s": r["wall_s"],
            }
        )
        save()
        print(
            f"env {n}: {r['useful_substeps_per_s']:,.0f} substeps/s, {r['env_steps_per_s']:,.0f} env steps/s, "
            f"compile {r['compile_s']:.0f} s",
            flush=True,
        )


def train_stages(cfg, learn_seconds: float, deadline: float, save) -> tuple[dict, dict]:
    """The train and learn stages; `save(stage, value)` records partial results as they come."""
    loop = cfg.train.loop
    runner = Runner(make_train(cfg.train, make_push_adapter(cfg.env, enc.load(None))))
    ts = runner.trainer.init(jax.random.PRNGKey(loop.seed))
    t0 = time.perf_counter()
    ts, m = runner.iteration(ts)
    first = time.perf_counter() - t0
    first_parts = {"first_batch_rollout_s": m["rollout_s"], "first_batch_learn_s": m["learn_s"]}
    save("train", {"num_envs": loop.num_envs, "first_batch_s": first, **first_parts, "timed_batches": 0})
    batches = []
    stop = min(time.perf_counter() + learn_seconds, deadline)
    while time.perf_counter() < stop and int(ts.env_steps) < loop.total_env_steps:
        ts, m = runner.iteration(ts)
        batches.append({"rollout_s": m["rollout_s"], "learn_s": m["learn_s"], "learning": bool(m["learning"])})
    steps_per_batch = loop.env_steps_per_iteration(cfg.env.episode_length)
    updates_per_batch = loop.updates_per_iteration(cfg.env.episode_length)
    train = {
        "num_envs": loop.num_envs,
        "env_steps_per_batch": steps_per_batch,
        "updates_per_batch": updates_per_batch,
        "first_batch_s": first,
        **first_parts,
        "timed_batches": len(batches),
    }
    learning = [b for b in batches if b["learning"]]  # warm-up batches make no updates
    if learning:
        roll = float(np.median([b["rollout_s"] for b in learning]))
        learn = float(np.median([b["learn_s"] for b in learning]))
        train.update(
            learning_batches=len(learning),
            rollout_s=roll,
            learn_s=learn,
            env_steps_per_s=steps_per_batch / (roll + learn),
            rollout_env_steps_per_s=steps_per_batch / roll,
            updates_per_s=updates_per_batch / learn,
        )
    print(f"train: first batch {first:.0f} s, {len(batches)} more batches", flush=True)
    if time.perf_counter() > deadline:
        return train, {"skipped": "time budget spent"}
    t0 = time.perf_counter()
    stats = jax.block_until_ready(runner.evaluate(ts.sac.actor_params))
    learn = {
        "env_steps": int(ts.env_steps),
        "episodes": loop.eval_episodes,
        "eval_s": time.perf_counter() - t0,
        **{k: float(v) for k, v in stats.items() if np.ndim(v) == 0},
    }
    print(
        f"learn: after {learn['env_steps']} env steps, within 1 / 5 cm {learn['success_1cm']:.2f} / "
        f"{learn['success_5cm']:.2f}, final distance {learn['final_distance']:.3f} m",
        flush=True,
    )
    return train, learn


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tiny", action="store_true", help="toy sizes for a CPU: " + json.dumps(TINY))
    p.add_argument("--sizes", type=int, nargs="+")
    p.add_argument("--preset", choices=presets.PRESETS)
    p.add_argument("--learn-seconds", type=float, help="training time after the first batch")
    p.add_argument("--env-steps", type=int, help="env steps per environment in the env stage")
    p.add_argument("--budget-s", type=float, help="stages that would start after this many seconds are skipped")
    p.add_argument("--out", type=Path, default=Path("outputs/gpu_check.json"))
    a = p.parse_args(argv)
    opts = dict(TINY if a.tiny else FULL)
    for k in opts:
        if getattr(a, k) is not None:
            opts[k] = getattr(a, k)
    if any(n < 1 for n in opts["sizes"]) or opts["env_steps"] < 1 or opts["learn_seconds"] < 0:
        p.error("--sizes and --env-steps must be >= 1 and --learn-seconds >= 0")
    start = time.perf_counter()
    deadline = start + opts["budget_s"]
    cfg = presets.make("vpm", opts["preset"], 0)
    if a.tiny:  # one more batch than the warm-up, so the timed batches learn
        cfg = presets.override(cfg, **{"loop.total_env_steps": 1200})
    record = {"machine": machine(), "options": opts, "stages": {"env": []}, "complete": False}

    def save(stage: str | None = None, value=None) -> None:
        if stage is not None:
            record["stages"][stage] = value
        record["wall_s"] = time.perf_counter() - start
        a.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = a.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=2) + "\n")
        tmp.replace(a.out)  # a reader (or a kill) never sees half a file

    rows = record["stages"]["env"]
    try:
        save()
        env_stage(cfg, opts["sizes"][:1], opts["env_steps"], deadline, rows, save)
        if time.perf_counter() > deadline:
            save("train", {"skipped": "time budget spent"})
            save("learn", {"skipped": "time budget spent"})
        else:
            train, learn = train_stages(cfg, opts["learn_seconds"], deadline, save)
            save("train", train)
            save("learn", learn)
        env_stage(cfg, opts["sizes"][1:], opts["env_steps"], deadline, rows, save)
        record["complete"] = True
    except KeyboardInterrupt:  # gpu_check.sh's timeout: keep what was measured, say why it stopped
        record["stopped"] = "interrupted (SIGINT: the wrapper's timeout or the user)"
        save()
        print(f"interrupted; wrote {a.out} ({record['wall_s']:.0f} s)")
        sys.exit(124)
    save()
    print(f"wrote {a.out} ({record['wall_s']:.0f} s)")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()
