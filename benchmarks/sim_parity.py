"""One trained policy in both simulators, episode by episode: MJX (`mjx-push eval`) against CPU MuJoCo
(`mjx-push deploy --sim cpu`), and where the two runs part.

    python -m benchmarks.sim_parity POLICY [POLICY ...] [--episodes 100] [--setting standard]
                                    [--shape all] [--seed 777] [--masks analytic render]
                                    [--obs-noise N] [--out outputs/bench_sim_parity.json]

POLICY is an exported .npz or ``pretrained:NAME``. Both simulators run the same episodes: the objects,
starts and goals of the evaluation protocol (`mjx_push.train.evaluate`, the given seed) are handed to the CPU
environment as well. In MJX the policy acts through JAX on analytic masks; on CPU through
`mjx_push.export.numpy_policy` on each mask source of ``--masks`` (``render``: the under-table camera rendered
by MuJoCo's OpenGL renderer and thresholded, as the real camera's pipeline; ``analytic``: the
projection MJX trains with).

Per episode and mask source it records, step by step, what each simulator's policy saw and did: the
object latent (MJX's recomputed from its recorded state with the analytic masks under NumPy and the
NumPy port of the encoder), the action, and after the step the object's xy and the flange's xy (both by C forward
kinematics from the joint positions). It reports, per shape and in all: success within the task's
radius in each simulator, the fraction of episodes whose outcome agrees, the correlation of final
distances, and the first step at which each quantity parts (latent, action, flange, object) and which
parts first. With rendered masks it also gives the latent gap of the mask source alone: on the CPU
run's own states, the rendered mask's latent against the analytic mask's.

``--obs-noise`` replaces the policy's observation noise on the flange xy in both simulators (0 removes
it: the two simulators draw it from different generators, so with noise the actions part from step 1
by the noise's effect alone). Prints tables, writes JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import numpy as np

# Parting thresholds: the object at the open-loop target's 1 mm, the flange at a tenth of it, a latent
# component by 0.01 (latents are O(0.1-1)), an action component by 0.01 of its [-1, 1] range.
TOLERANCES = {"latent": 0.01, "action": 0.01, "flange": 1e-4, "object": 1e-3}
# Within one step the policy reads the latent, then acts, then the physics moves flange and object:
# on a tie the earlier of these parted first.
ORDER = ("latent", "action", "flange", "object")


def parse(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="*", help="exported .npz files or pretrained:NAME")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--setting", default="standard")
    ap.add_argument("--shape", default="all")
    ap.add_argument("--seed", type=int, default=777, help="evaluation seed (use one other than the training seed)")
    ap.add_argument("--batch", type=int, default=20)
    ap.add_argument("--masks", nargs="+", default=["analytic", "render"], choices=["analytic", "render"])
    ap.add_argument("--obs-noise", type=float, help="flange-xy observation noise in both (default: the policy's)")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_sim_parity.json"))
    ap.add_argument(
        "--floor",
        nargs=2,
        type=Path,
        metavar=("A.json", "B.json"),
        help="run nothing: each simulator against itself over two of this benchmark's JSONs of the same "
        "policies and episodes that differ in --obs-noise (the agreement a sub-millimetre perturbation leaves)",
    )
    a = ap.parse_args(argv)
    if not a.policies and a.floor is None:
        ap.error("give POLICY ... to compare the simulators, or --floor A.json B.json")
    if a.episodes < 1 or a.batch < 1:
        ap.error("--episodes and --batch must be >= 1")
    if a.obs_noise is not None and not a.obs_noise >= 0:
        ap.error(f"--obs-noise must be >= 0, got {a.obs_noise}")
    return a


def first_step(diff, tol: float) -> int | None:
    """1-based first step whose difference exceeds `tol`, None if none does."""
    over = np.nonzero(np.asarray(diff) > tol)[0]
    return int(over[0]) + 1 if over.size else None


def parting(mjx: dict, cpu: dict) -> dict:
    """Where one episode's two runs part. `mjx` and `cpu` each hold per-step arrays over T steps:
    "latent" [T, L] and "action" [T, 3] (read and chosen at the start of each step), "flange" [T, 2]
    and "object" [T, 2] (after each step). Returns each quantity's per-step difference (max-abs for
    latent and action, Euclidean for positions), its first step over TOLERANCES, and which parted first."""
    diff = {}
    for k in ORDER:
        d = np.asarray(mjx[k], np.float64) - np.asarray(cpu[k], np.float64)
        diff[k] = np.linalg.norm(d, axis=-1) if k in ("flange", "object") else np.abs(d).max(axis=-1)
    first = {k: first_step(diff[k], TOLERANCES[k]) for k in ORDER}
    parted = [(first[k], ORDER.index(k), k) for k in ORDER if first[k] is not None]
    return {
        "diff": {k: v.tolist() for k, v in diff.items()},
        "first": first,
        "parts_first": min(parted)[2] if parted else "neither",
    }


def _stats(x) -> dict:
    x = np.asarray(x, np.float64)
    return {"episodes": int(x.size), "median": float(np.median(x)) if x.size else None}


def agreement(rows: list[dict]) -> dict:
    """Summary over episodes, each row {"mjx_success", "cpu_success", "mjx_final", "cpu_final",
    "parting"} (final distances in m): `mjx_push.export.metrics.agreement` (success in each simulator,
    per-episode agreement, the correlation of final distances) and the parting steps."""
    from mjx_push.export.metrics import agreement as outcome_agreement

    parts = {k: 0 for k in (*ORDER, "neither")}
    for r in rows:
        parts[r["parting"]["parts_first"]] += 1
    return {
        **outcome_agreement(*([r[k] for r in rows] for k in ("mjx_success", "mjx_final", "cpu_success", "cpu_final"))),
        "first_step": {k: _stats([r["parting"]["first"][k] for r in rows if r["parting"]["first"][k]]) for k in ORDER},
        "parts_first": parts,
    }


def mjx_run(policy, env_cfg, spec):
    """The protocol's episodes in MJX, each with its recorded joint positions and actions."""
    from mjx_push.train.evaluate import evaluator_for

    ev = evaluator_for(env_cfg, policy.config.train.agent, spec.batch)
    out = ev.evaluate(policy, spec)
    return ev, out["per_episode"], out["recorded"]


def flange_xy(sim):
    """Flange xy from joint positions by C forward kinematics: both simulators' flange from one
    formula, at the positions after the step (MjData.site_xpos after mj_step is from before its
    integration, one substep behind)."""
    import mujoco

    scratch = mujoco.MjData(sim.model)

    def flange(q):
        scratch.qpos[:] = q
        mujoco.mj_kinematics(sim.model, scratch)
        return scratch.site_xpos[sim.ids.flange_site][:2].copy()

    return flange


def mjx_trajectory(rec: dict, sim, numpy_policy) -> dict:
    """Per-step latent/flange/object of a recorded MJX episode, read with CPU MuJoCo's kinematics and
    the NumPy analytic masks (the same projection as MJX's)."""
    from mjx_push import mask_geometry
    from mjx_push.export.cpu_env import quat_yaw

    a, flange = sim.ids.object_qpos, flange_xy(sim)
    qpos = np.asarray(rec["qpos"], np.float64)  # [T+1, nq]
    params = rec["params"]
    masks = np.stack(
        [
            mask_geometry.object_mask(rec["geom_type"], params.size, q[a : a + 2], quat_yaw(q[a + 3 : a + 7]), q[a + 2])
            for q in qpos[:-1]
        ]
    )
    return {
        "latent": numpy_policy.encode(masks),
        "action": np.asarray(rec["action"], np.float64),
        "flange": np.stack([flange(q) for q in qpos[1:]]),
        "object": qpos[1:, a : a + 2],
    }


def cpu_run(env, numpy_policy, rec: dict, seed: int, T: int) -> tuple[dict, dict, np.ndarray | None]:
    """One episode on CPU MuJoCo from the recorded episode's object: (trajectory, final info, latents of
    the analytic masks of the same states, when the env renders)."""
    from mjx_push import mask_geometry
    from mjx_push.export.cpu_env import quat_yaw

    obs = env.reset(seed=seed, params=rec["params"], geom_type=rec["geom_type"])
    numpy_policy.reset()
    z_goal = numpy_policy.encode(obs["goal_mask"])
    a, flange = env._s.ids.object_qpos, flange_xy(env._s)
    rendered = env.mask_source_used == "render"
    traj = {k: [] for k in ORDER}
    analytic = []
    for _ in range(T):
        z = numpy_policy.encode(obs["object_mask"])
        if rendered:
            q = env._s.data.qpos
            mask = mask_geometry.object_mask(
                env.geom_type, env.params.size, q[a : a + 2], quat_yaw(q[a + 3 : a + 7]), q[a + 2]
            )
            analytic.append(numpy_policy.encode(mask))
        action = numpy_policy.step_latent(z, z_goal, obs["ee_xy"])
        obs, _, _, _, info = env.step(action)
        traj["latent"].append(z)
        traj["action"].append(action)
        q = env._s.data.qpos
        traj["flange"].append(flange(q))
        traj["object"].append(q[a : a + 2].copy())
    return {k: np.asarray(v) for k, v in traj.items()}, info, (np.asarray(analytic) if rendered else None)


def compare(policy_ref: str, args) -> dict:
    from mjx_push.export.cpu_env import CpuPushEnv
    from mjx_push.export.numpy_policy import NumpyPolicy
    from mjx_push.export.policy_file import load_as_policy
    from mjx_push.export.pretrained import resolve
    from mjx_push.train.episodes import EvalSpec

    path = resolve(policy_ref)
    policy = load_as_policy(path)
    env_cfg = policy.config.env
    if args.obs_noise is not None:
        env_cfg = dataclasses.replace(env_cfg, obs_noise=args.obs_noise)
    spec = EvalSpec(
        setting=args.setting,
        shape=args.shape,
        episodes=args.episodes,
        seed=args.seed,
        batch=min(args.batch, args.episodes),
        record=args.episodes,
    )
    T, tau = env_cfg.episode_length, env_cfg.success_tau
    t0 = time.perf_counter()
    _, per, recorded = mjx_run(policy, env_cfg, spec)
    t_mjx = time.perf_counter() - t0
    numpy_policy = NumpyPolicy.from_file(path)
    result = {"policy": policy_ref, "agent": policy.config.agent, "obs_noise": env_cfg.obs_noise, "wall_s": {}}
    result["wall_s"]["mjx"] = t_mjx
    for source in args.masks:
        env = CpuPushEnv(env_cfg, mask_source=source)
        if env.mask_source_used != source:  # "render" refuses to fall back: this never happens silently
            raise RuntimeError(f"asked for {source} masks, got {env.mask_source_used}")
        t0 = time.perf_counter()
        rows, gaps = [], []
        for rec in recorded:
            i = rec["episode"]
            mjx_traj = mjx_trajectory(rec, env._sim(rec["geom_type"]), numpy_policy)
            cpu_traj, info, analytic = cpu_run(env, numpy_policy, rec, args.seed + i, T)
            if analytic is not None:
                gaps.append(np.abs(cpu_traj["latent"] - analytic).max(axis=-1))
            valid = not info["episode_invalid"]
            rows.append(
                {
                    "episode": int(i),
                    "geom_type": rec["geom_type"],
                    "mjx_success": bool(per["success"][i] > 0.5),
                    "cpu_success": bool(valid and info["distance"] < tau),
                    "mjx_final": float(per["final_distance"][i]),
                    "cpu_final": float(info["distance"]) if valid else float(per["start_distance"][i]),
                    "parting": parting(mjx_traj, cpu_traj),
                }
            )
        env.close()
        groups = {"all": rows, "cuboids": [r for r in rows if r["geom_type"] == "box"]}
        groups["cylinders"] = [r for r in rows if r["geom_type"] == "cylinder"]
        result[source] = {
            "summary": {g: agreement(v) for g, v in groups.items() if v},
            "episodes": rows,
        }
        if gaps:
            g = np.concatenate(gaps)
            result[source]["mask_source_latent_gap"] = {
                "median": float(np.median(g)),
                "p95": float(np.percentile(g, 95)),
                "max": float(g.max()),
                "steps_over_tol": float(np.mean(g > TOLERANCES["latent"])),
            }
        result["wall_s"][source] = time.perf_counter() - t0
    return result


def print_tables(results: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(width=170)
    for res in results:
        sources = [s for s in ("analytic", "render") if s in res]
        table = Table(title=f"{res['policy']} ({res['agent']}, obs noise {res['obs_noise']:g} m)")
        for col in (
            "masks",
            "shape",
            "MJX",
            "CPU",
            "agree",
            "corr.",
            "|Δ final| med. (mm)",
            "first step latent / action / flange / object",
            "parts first (l/a/f/o/none)",
        ):
            table.add_column(col, justify="right")
        for s in sources:
            for g, a in res[s]["summary"].items():
                firsts = " / ".join(
                    "-" if a["first_step"][k]["median"] is None else f"{a['first_step'][k]['median']:.0f}"
                    for k in ORDER
                )
                corr = "-" if a["final_distance_correlation"] is None else f"{a['final_distance_correlation']:.2f}"
                table.add_row(
                    s,
                    g,
                    f"{a['mjx_success']:.0%}",
                    f"{a['cpu_success']:.0%}",
                    f"{a['success_agreement']:.0%}",
                    corr,
                    f"{1e3 * a['final_distance_abs_diff_median_m']:.1f}",
                    firsts,
                    "/".join(str(a["parts_first"][k]) for k in (*ORDER, "neither")),
                )
        console.print(table)
        gap = res.get("render", {}).get("mask_source_latent_gap")
        if gap:
            console.print(
                f"rendered vs analytic mask latents on the CPU run's states: median {gap['median']:.4f}, "
                f"p95 {gap['p95']:.4f}, max {gap['max']:.4f}; {gap['steps_over_tol']:.0%} of steps over "
                f"{TOLERANCES['latent']}"
            )


def floor(a: dict, b: dict) -> list[dict]:
    """Each simulator against itself: for every policy and mask source in both runs `a` and `b` (this
    benchmark's JSONs over the same episodes), `mjx_push.export.metrics.agreement` of one run's outcomes with
    the other's, per simulator ("mjx" once, from the analytic entry; "cpu" per mask source)."""
    from mjx_push.export.metrics import agreement as outcome_agreement

    rows = []
    for ra, rb in zip(a["results"], b["results"]):
        if ra["policy"] != rb["policy"]:
            raise ValueError(f"the two runs hold different policies: {ra['policy']} against {rb['policy']}")
        for source in [s for s in ("analytic", "render") if s in ra and s in rb]:
            ea, eb = ra[source]["episodes"], rb[source]["episodes"]
            if [e["episode"] for e in ea] != [e["episode"] for e in eb]:
                raise ValueError(f"{ra['policy']} {source}: the two runs hold different episodes")
            for sim in ("mjx", "cpu") if source == "analytic" else ("cpu",):
                got = outcome_agreement(
                    *([e[f"{sim}_{k}"] for e in ep] for ep in (ea, eb) for k in ("success", "final"))
                )
                name = "MJX" if sim == "mjx" else f"CPU MuJoCo, {source} masks"
                rows.append(
                    {"policy": ra["policy"], "simulator": name, "noise": [ra["obs_noise"], rb["obs_noise"]], **got}
                )
    return rows


def main(argv=None) -> None:
    args = parse(argv)
    if args.floor is not None:
        rows = floor(*(json.loads(p.read_text()) for p in args.floor))
        for r in rows:
            corr = "-" if r["final_distance_correlation"] is None else f"{r['final_distance_correlation']:.2f}"
            print(
                f"{r['policy']:<18} {r['simulator']:<26} obs noise {r['noise'][0]:g} vs {r['noise'][1]:g} m: same "
                f"outcome {r['success_agreement']:.0%}, final distances r = {corr}, "
                f"|Δ final| median {1e3 * r['final_distance_abs_diff_median_m']:.1f} mm"
            )
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"floor": [str(p) for p in args.floor], "rows": rows}, indent=1) + "\n")
        print(f"written {args.out}")
        return
    results = [compare(p, args) for p in args.policies]
    print_tables(results)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    spec = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    args.out.write_text(json.dumps({"spec": spec, "tolerances": TOLERANCES, "results": results}, indent=1) + "\n")
    print(f"written {args.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()
