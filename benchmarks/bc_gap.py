"""Where a trained actor departs from the scripted expert it clones, and how much of that departure no
actor that cannot see a cuboid's orientation can avoid.

    python -m benchmarks.bc_gap [POLICY ...] [--experts] [--setting difficult] [--shape any]
        [--episodes 96] [--seed 1000003] [--yaws 16] [--out outputs/bc_gap.json]

POLICY is a run directory, a saved policy (best_policy.msgpack), an exported .npz or a shipped policy
(``pretrained:NAME``). Each is played deterministically on the protocol's episodes of ``--setting``
(objects of ``--shape``, any by default) in MJX, through the training rollout with the expert's
labels stored (the states the agent itself reaches, DAgger's view), and at every step of every valid
episode its action is compared with the expert's noise-free action there. Steps are grouped by shape
(cylinder, square cuboid, rectangular cuboid) and by how far the object still is from its goal
(``travel`` >= 3 cm, ``finish`` 1-3 cm, ``hold`` < 1 cm: the finish is where 1 cm is won or lost),
and, separately, by the mode the expert acts in at that state (``hold``, ``push``, ``approach``:
straight to the push point, ``circle``: round the object; its action jumps where the mode switches).
``share`` is a group's part of its shape's summed error. The ``circle`` steps are split once more by
how far round the object the rod stands (its angle off the push line, ``ANGLE_BINS``), with the share
of them where the actor turns round the object the other way from the expert (``other side``): near
180 degrees, right in front of the object, the expert's short way round changes side on a hair's
difference, and a cloner that cannot place that hair averages the two ways into standing still.

The yaw floor: at the same states, the expert's action with a cuboid's yaw replaced by each of
``--yaws`` values spread over its symmetry period (90 degrees for a square footprint, 180 for a
rectangular one), everything else unchanged. An actor whose observation carries no orientation (the
shipped encoder's latent does not: benchmarks/latent_precision.py) can at best predict the mean of
those actions, so their variance is the part of the cloning error it cannot avoid. Errors are squared
distances in the action box's units, summed over (a_x, a_y, a_s), as the cloning term measures them.
The first yaw is the true one, so its action must equal the stored label (checked).

``--experts``: whether a cuboid's orientation is needed at all. The scripted expert and its yaw-blind
mean (at every step the mean of its actions over the ``--yaws`` yaws, the best a cloner without the
orientation can imitate) push the same episodes; their success within 1 cm per shape is the answer.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax
import jax.numpy as jnp
import numpy as np
from rich.console import Console
from rich.table import Table

from mjx_push import expert as expert_mod
from mjx_push.train import presets
from mjx_push.train.runs import atomic
from mjx_push import encoder as enc
from mjx_push.train.loop import Runner, make_train
from mjx_push.train.push_task import PRIV, expert_ground_truth, make_push_adapter
from mjx_push.train.rollout import REPORT_RADII

SHAPES = ("cylinder", "square", "rectangular")
PHASES = (("travel", 0.03, np.inf), ("finish", 0.01, 0.03), ("hold", 0.0, 0.01))
SQUARE_TOL = 1e-3  # m: half extents closer than this make a square footprint
# Bins of the rod's angle off the push line (degrees) for the circling steps: 180 is right in front.
ANGLE_BINS = ((0, 90), (90, 135), (135, 160), (160, 181))


def play(config, actor_params, encoder_params, setting: str, seed: int, episodes: int, expert=None, shape="any"):
    """Deterministic episodes of the protocol (as numpy arrays) with the expert's labels: the actor's,
    or with ``expert`` (a function of one environment's expert inputs -> action) that expert's."""
    cfg = presets.with_overrides(
        config,
        {
            "train.loop.eval_setting": setting,
            "train.loop.eval_seed": seed,
            "train.loop.eval_episodes": episodes,
            "env.objects.shape": shape,
        },
    )
    adapter = make_push_adapter(cfg.env, encoder_params, expert_config=cfg.expert)
    if expert is not None:  # the rollout's expert environments then follow this one
        adapter = dataclasses.replace(
            adapter, expert=lambda obs, info: jax.vmap(expert)(expert_ground_truth(obs["priv"], info["goal_xy"]))
        )
    runner = Runner(make_train(cfg.train, adapter))
    n = cfg.train.loop.num_envs
    flags = (jnp.asarray(False), jnp.asarray(True), jnp.full((n,), expert is not None))
    parts = []
    for c, ep in enumerate(runner.eval_chunks()):
        out, stats = runner.rollout(actor_params, jax.random.PRNGKey(c), *flags, episodes=ep)
        keep = {k: out[k] for k in ("action", "expert_action", "priv", "goal_xy", "valid")}
        final = stats["episode_final_distance"]
        parts.append(jax.device_get({**keep, "final_distance": final, "index": ep["index"]}))
    flat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    chosen = flat["index"] < episodes
    return {k: v[chosen] for k, v in flat.items()}, cfg


def shape_of(priv: np.ndarray) -> np.ndarray:
    """[...] index into SHAPES from the privileged state."""
    size = priv[..., PRIV["size"]]
    box = priv[..., PRIV["is_box"]][..., 0] > 0.5
    return np.where(~box, 0, np.where(np.abs(size[..., 0] - size[..., 1]) < SQUARE_TOL, 1, 2))


def yaw_shifts(size, yaws: int):
    """[K] yaw offsets spreading ``yaws`` values over one environment's footprint symmetry period."""
    period = jnp.where(jnp.abs(size[0] - size[1]) < SQUARE_TOL, jnp.pi / 2, jnp.pi)
    return period * jnp.arange(yaws) / yaws


def yaw_actions(cfg, gt: dict, yaws: int) -> jax.Array:
    """[K, 3] the expert's actions in one environment at ``yaws`` yaws over its footprint's symmetry
    period, the first the true yaw."""
    shifts = yaw_shifts(gt["size"], yaws)
    return jax.vmap(lambda d: expert_mod.act(cfg.expert, cfg.env, {**gt, "object_yaw": gt["object_yaw"] + d}))(shifts)


def blind_expert(cfg, yaws: int):
    """The expert's action averaged over ``yaws`` yaws of the object: what it does not knowing them."""
    return lambda gt: jnp.mean(yaw_actions(cfg, gt, yaws), axis=0)


def yaw_floor(cfg, priv: np.ndarray, goal_xy: np.ndarray, yaws: int) -> tuple[np.ndarray, np.ndarray]:
    """Per state: the expert's actions at ``yaws`` yaws over the footprint's symmetry period (the first
    the true yaw) -> (their variance summed over the action's dimensions, the true-yaw action)."""
    gt = expert_ground_truth(jnp.asarray(priv), jnp.asarray(goal_xy))
    actions = np.asarray(jax.jit(jax.vmap(lambda g: yaw_actions(cfg, g, yaws)))(gt))  # [S, K, 3]
    var = np.sum(np.mean((actions - actions.mean(axis=1, keepdims=True)) ** 2, axis=1), axis=-1)
    return var, actions[:, 0]


def analyse(run: dict, cfg, yaws: int) -> dict:
    valid = run["valid"]
    T = run["action"].shape[1]
    priv = run["priv"][valid, :T].reshape(-1, run["priv"].shape[-1])  # the state each action was taken in
    goal = np.repeat(run["goal_xy"][valid], T, axis=0)
    action = run["action"][valid].reshape(-1, 3)
    label = run["expert_action"][valid].reshape(-1, 3)
    floor, true_yaw_action = yaw_floor(cfg, priv, goal, yaws)
    mismatch = float(np.max(np.abs(true_yaw_action - label))) if len(label) else 0.0
    if mismatch > 1e-4:
        raise RuntimeError(f"the expert recomputed from the stored state differs from its label by {mismatch}")
    err = np.sum((action - label) ** 2, axis=-1)
    shape = shape_of(priv)
    dist = np.linalg.norm(priv[:, PRIV["object_xy"]] - goal, axis=-1)
    modes = expert_modes(cfg, priv, goal)
    off, turn_actor, turn_label = circling(priv, goal, action, label)

    def row(m, **key):
        return {
            **key,
            "steps": int(m.sum()),
            "actor_error": float(err[m].mean()),
            "actor_error_by_dim": np.mean((action[m] - label[m]) ** 2, axis=0).round(5).tolist(),
            "yaw_floor": float(floor[m].mean()),
            # this group's part of the shape's summed cloning error: where the error mass is
            "error_share": float(err[m].sum() / max(err[shape == key_shape(key)].sum(), 1e-12)),
        }

    def key_shape(key):
        return SHAPES.index(key["shape"])

    rows, mode_rows, circle_rows = [], [], []
    for s, shape_name in enumerate(SHAPES):
        for phase, lo, hi in (("all", 0.0, np.inf), *PHASES):
            m = (shape == s) & (dist >= lo) & (dist < hi)
            if m.any():
                rows.append(row(m, shape=shape_name, phase=phase))
        for k, mode_name in enumerate(expert_mod.MODES):
            m = (shape == s) & (modes == k)
            if m.any():
                mode_rows.append(row(m, shape=shape_name, mode=mode_name))
        circle = (shape == s) & (np.asarray(expert_mod.MODES)[modes] == "circle")
        for lo, hi in ANGLE_BINS:
            m = circle & (off >= lo) & (off < hi)
            if m.any():
                # the expert turns (its tangential offset is at least a tenth of the box) and the actor
                # turns the other way round the object
                other = (np.abs(turn_label[m]) > 0.1) & (np.sign(turn_actor[m]) != np.sign(turn_label[m]))
                circle_rows.append(
                    {**row(m, shape=shape_name, off_deg=[lo, min(hi, 180)]), "other_side": float(other.mean())}
                )
    return {
        "episodes": int(valid.sum()),
        "invalid": int((~valid).sum()),
        "rows": rows,
        "mode_rows": mode_rows,
        "circle_rows": circle_rows,
        "success": success(run),
    }


def circling(priv: np.ndarray, goal_xy: np.ndarray, action: np.ndarray, label: np.ndarray):
    """Per state: the rod's angle off the push line (degrees, 0 right behind the object, 180 right in
    front of it), and the actor's and the expert's a_xy across the object->rod direction (positive:
    counter-clockwise round the object), in the action box's units."""
    rel = priv[:, PRIV["ee_xy"]] - priv[:, PRIV["object_xy"]]
    to_goal = goal_xy - priv[:, PRIV["object_xy"]]
    u = to_goal / np.maximum(np.linalg.norm(to_goal, axis=-1, keepdims=True), 1e-9)
    n = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    off = np.degrees(np.abs(np.arctan2(np.sum(rel * n, -1), -np.sum(rel * u, -1))))
    r = rel / np.maximum(np.linalg.norm(rel, axis=-1, keepdims=True), 1e-9)
    tangent = np.stack([-r[:, 1], r[:, 0]], axis=-1)
    return off, np.sum(action[:, :2] * tangent, -1), np.sum(label[:, :2] * tangent, -1)


def expert_modes(cfg, priv: np.ndarray, goal_xy: np.ndarray) -> np.ndarray:
    """Per state: the index into expert.MODES of the mode the expert acts in there."""
    gt = expert_ground_truth(jnp.asarray(priv), jnp.asarray(goal_xy))
    return np.asarray(jax.jit(jax.vmap(lambda g: expert_mod.mode(cfg.expert, g)))(gt))


def success(run: dict) -> dict:
    """Per shape: episodes, and the share ending within each report radius (invalid ones fail)."""
    shape = shape_of(run["priv"][:, 0])
    out = {}
    for s, name in enumerate(SHAPES):
        m = shape == s
        if m.any():
            ok = run["valid"][m][:, None] & (run["final_distance"][m][:, None] < np.asarray(REPORT_RADII)[None])
            out[name] = {
                "episodes": int(m.sum()),
                **{f"{round(r * 100)}cm": float(v) for r, v in zip(REPORT_RADII, ok.mean(0))},
            }
    return out


def experts(setting: str, seed: int, episodes: int, yaws: int, shape: str = "any") -> dict:
    """The scripted expert and its yaw-blind mean on the same episodes (the cpu-long preset's box)."""
    cfg = presets.make("vpm", "cpu-long")
    encoder_params = enc.load(None)
    actor_params = (
        Runner(make_train(cfg.train, make_push_adapter(cfg.env, encoder_params)))
        .init(jax.random.PRNGKey(0))
        .sac.actor_params
    )  # unused: every environment follows the expert
    full = lambda gt: expert_mod.act(cfg.expert, cfg.env, gt)  # noqa: E731
    out = {}
    for name, fn in (("expert", full), ("yaw-blind expert", blind_expert(cfg, yaws))):
        run, _ = play(cfg, actor_params, encoder_params, setting, seed, episodes, expert=fn, shape=shape)
        out[name] = success(run)
    return out


def group_name(r: dict) -> str:
    if "phase" in r:
        return r["phase"]
    if "mode" in r:
        return f"expert {r['mode']}"
    lo, hi = r["off_deg"]
    return f"circle {lo}-{hi} deg, {100 * r['other_side']:.0f} % other side"


def main(argv=None) -> None:
    xla.use_cpu_devices()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policies", nargs="*")
    ap.add_argument("--experts", action="store_true", help="also the scripted expert and its yaw-blind mean")
    ap.add_argument("--setting", default="difficult", choices=("standard", "difficult"))
    ap.add_argument("--shape", default="any", choices=("any", "cylinder", "cuboid", "square", "rectangular"))
    ap.add_argument(
        "--episodes", type=int, default=96, help="protocol episodes (a multiple of the batch plays whole chunks)"
    )
    ap.add_argument("--seed", type=int, default=1_000_003, help="the protocol's seed (default: its test seed)")
    ap.add_argument("--yaws", type=int, default=16)
    ap.add_argument("--out", type=Path, default=Path("outputs/bc_gap.json"))
    args = ap.parse_args(argv)
    from mjx_push.export import pretrained
    from mjx_push.export.policy_file import load_as_policy
    from mjx_push.cli.options import resolve_policy

    console = Console()
    result = {
        "setting": args.setting,
        "shape": args.shape,
        "seed": args.seed,
        "episodes": args.episodes,
        "yaws": args.yaws,
        "policies": {},
    }
    for path in args.policies:
        t0 = time.perf_counter()
        file = pretrained.resolve(path)
        policy = load_as_policy(file) if file.suffix == ".npz" else resolve_policy(file)
        run, cfg = play(
            policy.config,
            policy.actor_params,
            policy.encoder_params,
            args.setting,
            args.seed,
            args.episodes,
            shape=args.shape,
        )
        res = analyse(run, cfg, args.yaws)
        res.update(agent=policy.config.agent, wall_s=round(time.perf_counter() - t0, 1))
        result["policies"][str(path)] = res
        table = Table(
            title=f"{path} ({policy.config.agent}): actor vs expert, squared error per step "
            f"({res['episodes']} valid episodes, {args.setting})"
        )
        cols = ("shape", "group", "steps", "actor error", "share", "a_x / a_y / a_s", "yaw floor", "floor / error")
        for col in cols:
            table.add_column(col, justify="right")
        for r in res["rows"] + res["mode_rows"] + res["circle_rows"]:
            table.add_row(
                r["shape"],
                group_name(r),
                str(r["steps"]),
                f"{r['actor_error']:.3f}",
                f"{r['error_share']:.2f}",
                " / ".join(f"{v:.3f}" for v in r["actor_error_by_dim"]),
                f"{r['yaw_floor']:.3f}",
                f"{r['yaw_floor'] / max(r['actor_error'], 1e-9):.2f}",
            )
        console.print(table)
    if args.experts:
        result["experts"] = experts(args.setting, args.seed, args.episodes, args.yaws, args.shape)
    runs = {**{str(p): r["success"] for p, r in result["policies"].items()}, **result.get("experts", {})}
    table = Table(title=f"within 1 / 2 / 5 cm, {args.setting} ({args.episodes} episodes)")
    table.add_column("who")
    for name in SHAPES:
        table.add_column(name, justify="right")
    for who, by_shape in runs.items():
        cells = [
            " / ".join(f"{100 * v[k]:.0f}" for k in ("1cm", "2cm", "5cm")) if v else "-"
            for v in (by_shape.get(n) for n in SHAPES)
        ]
        table.add_row(who, *cells)
    console.print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(args.out, json.dumps(result, indent=1) + "\n")
    console.print(f"JSON: {args.out}")


if __name__ == "__main__":
    main()
