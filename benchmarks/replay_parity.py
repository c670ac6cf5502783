"""Open-loop replay: the same actions in MJX and in CPU MuJoCo, step by step, and where they part.

    python -m benchmarks.replay_parity [--policy expert|POLICY.npz] [--preset cpu] [--episodes 100]
                                       [--setting standard] [--seed 777] [--x64] [--contacts]
                                       [--iterations N] [--ls-iterations N]
                                       [--out outputs/bench_replay_parity.json]

MJX runs the evaluation protocol's episodes (`mjx_push.train.evaluate`, the given seed) closed-loop with the
policy (default: the scripted expert, which pushes in every episode) and records every step's joint
positions and actions. CPU MuJoCo (`mjx_push.export.cpu_env.CpuPushEnv`: C `mj_step`, float64, the controller law
under NumPy) then starts each episode from the same object and replays the same actions
open-loop. No policy and no mask enters the comparison: what differs is the two engines (collision
code, solver, float32 against float64) and the two controller implementations.

Per step it compares the object's xy and yaw and the flange's xy (from the joint positions by forward
kinematics in C MuJoCo, so both sides' flange comes from the same formula). Reported per shape and in
all: the object xy difference after the last step (median, 95th percentile, max), the fraction of
episodes within 1 mm, the first step at which the object parts by more than 1 mm and the flange by
more than 0.1 mm, and which parts first. `--x64` runs MJX in float64 (jax_enable_x64), which separates
float32 rounding from the engines' own differences; `--iterations` / `--ls-iterations` set both
simulators' solver iterations (convergence against the engines' solvers). `--contacts` also steps
each episode to its first rod-object contact in C MuJoCo and hands that very state to MJX's forward
pass: how often MJX finds no contact where C MuJoCo finds one, the contact count, depth and normal, and
the object's acceleration. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from mjx_push import xla  # the CPU fusion-emitter flag on import (before jax)
import jax

OBJECT_TOL = 1e-3  # m: the open-loop target
FLANGE_TOL = 1e-4  # m


def parse(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", default="expert", help="'expert' or an exported .npz (or pretrained:NAME)")
    ap.add_argument("--preset", default="cpu", help="the expert's environment (ignored with a policy file)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--setting", default="standard")
    ap.add_argument("--seed", type=int, default=777)
    ap.add_argument("--batch", type=int, default=20)
    ap.add_argument("--x64", action="store_true", help="MJX in float64")
    ap.add_argument(
        "--contacts",
        action="store_true",
        help="also compare both engines' contacts at each episode's first rod-object contact",
    )
    ap.add_argument("--iterations", type=int, help="solver iterations in both simulators (default: the config's)")
    ap.add_argument("--ls-iterations", type=int, help="line-search iterations in both (default: the config's)")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_replay_parity.json"))
    a = ap.parse_args(argv)
    if a.episodes < 1 or a.batch < 1:
        ap.error("--episodes and --batch must be >= 1")
    return a


def first_over(diff, tol: float) -> int | None:
    """1-based first step whose difference exceeds `tol`, None if none does."""
    import numpy as np

    over = np.nonzero(np.asarray(diff) > tol)[0]
    return int(over[0]) + 1 if over.size else None


def replay(cfg, rec: dict) -> dict:
    """Replay one recorded MJX episode in CPU MuJoCo; per-step differences."""
    import mujoco
    import numpy as np

    from mjx_push.export.cpu_env import CpuPushEnv, quat_yaw

    env = CpuPushEnv(cfg.env, mask_source="analytic")
    env.reset(params=rec["params"], geom_type=rec["geom_type"])
    sim = env._sim(rec["geom_type"])
    m, ids = sim.model, sim.ids
    scratch = mujoco.MjData(m)
    a = ids.object_qpos

    def flange(qpos):
        scratch.qpos[:] = qpos
        mujoco.mj_kinematics(m, scratch)
        return scratch.site_xpos[ids.flange_site][:2].copy()

    qpos_mjx = np.asarray(rec["qpos"], np.float64)
    start = float(np.abs(env._s.data.qpos - qpos_mjx[0]).max())
    obj, yaw, fl, subs = [], [], [], []
    for t, action in enumerate(np.asarray(rec["action"], np.float64)):
        _, _, _, _, info = env.step(action)
        q_cpu, q_mjx = env._s.data.qpos, qpos_mjx[t + 1]
        obj.append(float(np.linalg.norm(q_cpu[a : a + 2] - q_mjx[a : a + 2])))
        dyaw = quat_yaw(q_cpu[a + 3 : a + 7]) - quat_yaw(q_mjx[a + 3 : a + 7])
        yaw.append(float(abs((dyaw + np.pi) % (2 * np.pi) - np.pi)))
        fl.append(float(np.linalg.norm(flange(q_cpu) - flange(q_mjx))))
        subs.append(info["substeps"] == int(rec["substeps"][t]))
    moved = float(np.linalg.norm(qpos_mjx[-1][a : a + 2] - qpos_mjx[0][a : a + 2]))
    return {
        "episode": rec["episode"],
        "geom_type": rec["geom_type"],
        "start_diff": start,
        "object": obj,
        "yaw": yaw,
        "flange": fl,
        "same_substeps": bool(all(subs)),
        "object_moved": moved,
        "object_first": first_over(obj, OBJECT_TOL),
        "flange_first": first_over(fl, FLANGE_TOL),
    }


def first_contact(cfg, rec: dict, forward) -> dict | None:
    """Step the episode in CPU MuJoCo one substep at a time up to the first rod-object contact, then
    hand that very state to MJX's forward pass (`forward(model, data)`) and compare the two engines'
    rod-object contacts (count, penetration, normal) and the object's resulting acceleration."""
    import mujoco
    import numpy as np
    from mujoco import mjx

    from mjx_push.export.cpu_env import CpuPushEnv, decode_substeps, flange_target

    env = CpuPushEnv(cfg.env, mask_source="analytic")
    env.reset(params=rec["params"], geom_type=rec["geom_type"])
    m, d, ids = env._s.model, env._s.data, env._s.ids
    pair = {ids.rod_geom, ids.object_geom}
    v = slice(ids.object_qvel, ids.object_qvel + 3)
    for t, action in enumerate(np.asarray(rec["action"], np.float64)):
        env.target = flange_target(
            d.site_xpos[ids.flange_site][:2],
            action[:2],
            cfg.env.action_scale,
            cfg.env.workspace_x,
            cfg.env.workspace_y,
            env.home_flange[2],
        )
        for k in range(decode_substeps(action[2], cfg.env.substeps)):
            env.run_substeps(1)
            mujoco.mj_forward(m, d)  # contacts at the current positions (mj_step's are from before it)
            c_cpu = [c for c in d.contact[: d.ncon] if {c.geom1, c.geom2} == pair]
            if not c_cpu:
                continue
            dm = forward(mjx.put_model(m), mjx.put_data(m, d))
            con = dm._impl.contact if hasattr(dm, "_impl") and hasattr(dm._impl, "contact") else dm.contact
            geom, dist = np.asarray(con.geom), np.asarray(con.dist)
            active = [i for i in range(len(dist)) if set(geom[i].tolist()) == pair and dist[i] < 0]
            acc_cpu, acc_mjx = d.qacc[v].copy(), np.asarray(dm.qacc)[v]
            return {
                "step": t + 1,
                "substep": k + 1,
                "cpu_contacts": len(c_cpu),
                "mjx_contacts": len(active),
                "cpu_depth": float(-min(c.dist for c in c_cpu)),
                "mjx_depth": float(-dist[active].min()) if active else 0.0,
                "normal_angle_deg": float(
                    np.degrees(
                        np.arccos(np.clip(abs(np.dot(c_cpu[0].frame[:3], np.asarray(con.frame)[active[0]][0])), 0, 1))
                    )
                )
                if active
                else None,
                "object_acc_rel_diff": float(np.linalg.norm(acc_mjx - acc_cpu) / max(np.linalg.norm(acc_cpu), 1e-9)),
            }
    return None


def contact_summary(found: list[dict]) -> dict:
    import numpy as np

    if not found:
        return {"episodes": 0}
    missed = [f for f in found if f["mjx_contacts"] == 0]
    seen = [f for f in found if f["mjx_contacts"] > 0]
    return {
        "episodes": len(found),
        "mjx_misses_the_contact": len(missed) / len(found),
        "same_contact_count": float(np.mean([f["mjx_contacts"] == f["cpu_contacts"] for f in found])),
        "depth_diff_median_mm": float(np.median([1e3 * abs(f["mjx_depth"] - f["cpu_depth"]) for f in seen]))
        if seen
        else None,
        "normal_angle_median_deg": float(np.median([f["normal_angle_deg"] for f in seen])) if seen else None,
        "object_acc_rel_diff_median": float(np.median([f["object_acc_rel_diff"] for f in seen])) if seen else None,
    }


def parity_summary(rows: list[dict]) -> dict:
    import numpy as np

    final = np.array([r["object"][-1] for r in rows])
    yaw = np.degrees([r["yaw"][-1] for r in rows])
    obj_first = [r["object_first"] for r in rows if r["object_first"] is not None]
    fl_first = [r["flange_first"] for r in rows if r["flange_first"] is not None]
    order = {"flange": 0, "object": 0, "same step": 0, "neither": 0}
    for r in rows:
        o, f = r["object_first"], r["flange_first"]
        key = (
            "neither"
            if o is None and f is None
            else "object"
            if f is None or (o is not None and o < f)
            else "flange"
            if o is None or f < o
            else "same step"
        )
        order[key] += 1
    return {
        "episodes": len(rows),
        "within_1mm": float(np.mean(final < OBJECT_TOL)),
        "final_object_diff_m": {
            "median": float(np.median(final)),
            "p95": float(np.percentile(final, 95)),
            "max": float(final.max()),
        },
        "final_yaw_diff_deg": {"median": float(np.median(yaw)), "p95": float(np.percentile(yaw, 95))},
        "object_parts_at_step": {
            "episodes": len(obj_first),
            "median": float(np.median(obj_first)) if obj_first else None,
        },
        "flange_parts_at_step": {"episodes": len(fl_first), "median": float(np.median(fl_first)) if fl_first else None},
        "parts_first": order,
        "same_substeps": float(np.mean([r["same_substeps"] for r in rows])),
        "start_diff_max": float(max(r["start_diff"] for r in rows)),
        "object_moved_median_m": float(np.median([r["object_moved"] for r in rows])),
    }


def main(argv=None) -> None:
    a = parse(argv)
    if a.x64:
        jax.config.update("jax_enable_x64", True)
    from rich.console import Console
    from rich.table import Table

    from mjx_push.train import presets
    from mjx_push.train.evaluate import ExpertPolicy, evaluate
    from mjx_push.train.episodes import EvalSpec

    console = Console()
    if a.policy == "expert":
        cfg = presets.make("vpm", a.preset, 0)
        policy = ExpertPolicy(cfg)
    else:
        from mjx_push.export import pretrained
        from mjx_push.export.policy_file import load_as_policy

        policy = load_as_policy(pretrained.resolve(a.policy))
        cfg = policy.config
    if a.iterations or a.ls_iterations:
        import dataclasses

        solver = dataclasses.replace(
            cfg.env.solver, **{k: v for k, v in (("iterations", a.iterations), ("ls_iterations", a.ls_iterations)) if v}
        )
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, solver=solver))
        policy = dataclasses.replace(policy, config=cfg)
    spec = EvalSpec(
        setting=a.setting,
        shape="all",
        episodes=a.episodes,
        seed=a.seed,
        batch=min(a.batch, a.episodes),
        record=a.episodes,
    )
    t0 = time.perf_counter()
    recorded = evaluate(policy, spec)["recorded"]
    t_mjx = time.perf_counter() - t0
    t0 = time.perf_counter()
    rows = [replay(cfg, rec) for rec in recorded]
    t_cpu = time.perf_counter() - t0
    groups = {
        "all": rows,
        "box": [r for r in rows if r["geom_type"] == "box"],
        "cylinder": [r for r in rows if r["geom_type"] == "cylinder"],
    }
    summary = {k: parity_summary(v) for k, v in groups.items() if v}
    if a.contacts:
        forward = jax.jit(__import__("mujoco.mjx", fromlist=["forward"]).forward)
        found = {r["episode"]: first_contact(cfg, rec, forward) for r, rec in zip(rows, recorded)}
        for r in rows:
            r["first_contact"] = found[r["episode"]]
        for k, v in groups.items():
            if v:
                summary[k]["first_contact"] = contact_summary([r["first_contact"] for r in v if r["first_contact"]])

    title = (
        f"open-loop replay, {a.policy}, {a.episodes} {a.setting} episodes (seed {a.seed}), "
        f"MJX {'float64' if a.x64 else 'float32'} vs CPU MuJoCo float64, solver {cfg.env.solver.iterations} / "
        f"{cfg.env.solver.ls_iterations} iterations"
    )
    table = Table(title=title)
    for col in (
        "shape",
        "eps",
        "within 1 mm",
        "final diff median / p95 / max (mm)",
        "yaw median / p95 (deg)",
        "object parts (eps, median step)",
        "flange parts (eps, median step)",
        "parts first f/o/same/none",
    ):
        table.add_column(col, justify="right")
    for k, s in summary.items():
        f, y, o, fl, p = (
            s["final_object_diff_m"],
            s["final_yaw_diff_deg"],
            s["object_parts_at_step"],
            s["flange_parts_at_step"],
            s["parts_first"],
        )
        table.add_row(
            k,
            str(s["episodes"]),
            f"{s['within_1mm']:.0%}",
            f"{1e3 * f['median']:.3f} / {1e3 * f['p95']:.2f} / {1e3 * f['max']:.1f}",
            f"{y['median']:.2f} / {y['p95']:.1f}",
            f"{o['episodes']}, {o['median']}",
            f"{fl['episodes']}, {fl['median']}",
            f"{p['flange']}/{p['object']}/{p['same step']}/{p['neither']}",
        )
    console.print(table)
    for k, s in summary.items():
        if "first_contact" in s:
            console.print(f"first rod-object contact, {k}: {json.dumps(s['first_contact'])}")
    console.print(
        f"start states differ by at most {summary['all']['start_diff_max']:.2e}; same substeps in "
        f"{summary['all']['same_substeps']:.0%} of episodes; objects moved "
        f"{100 * summary['all']['object_moved_median_m']:.1f} cm (median); MJX {t_mjx:.0f} s "
        f"(compile included), CPU {t_cpu:.0f} s"
    )
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(
        json.dumps(
            {
                "args": {k: str(v) for k, v in vars(a).items()},
                "summary": summary,
                "episodes": rows,
                "wall_s": {"mjx": t_mjx, "cpu": t_cpu},
                "argv": sys.argv,
            },
            indent=1,
        )
        + "\n"
    )
    console.print(f"written {a.out}")


if __name__ == "__main__":
    xla.use_cpu_devices()  # one CPU device per core, as the mjx-push command does
    main()
