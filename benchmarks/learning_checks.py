"""Learning checks: does the learner still learn? Each check trains a small agent from scratch and
scores it against a threshold; the test suite keeps the mechanics (what is stored, when updates run,
what is selected, what compiles) and CI runs these after it.

    python -m benchmarks.learning_checks [--only toy-vpm scene-imitation ...] [--out outputs/learning_checks.json]

Checks (each alone on 2 CPU cores takes about a minute, compilation included):
- toy-vpm, toy-ugru: plain SAC + HER on the toy task (tests/toy.py: a point moved by the action, seen
  through a fixed linear "encoder") reaches >= 90 % success on held-out episodes at 1,600 / 1,920 env
  steps, from under 20 % untrained, its final distances under the success radius.
- toy-all-features: every learner feature at once (normalisation, privileged critic, cloning, the
  radius curriculum) reaches >= 90 % in-run success on the toy task at 1,280 env steps.
- toy-two-processes: the toy task of toy-vpm trained as one data-parallel run of two processes on
  localhost (one CPU device each, `jax.distributed`, as `--num-processes 2`) reaches the same >= 90 %
  in-run success at 1,600 env steps, both processes reporting the same.
- expert-1cm: the scripted expert, the teacher of every preset, pushes each of 8 standard episodes
  (both shapes) to within 1 cm, every object ending under half its starting distance.
- scene-imitation: on the MJX pushing scene (one cylinder, 10-step episodes), cloning the expert's
  labels brings a latent-observing VPM actor within 0.6 of the best state-blind actor's squared error
  on held-out expert episodes, its move direction's cosine with the expert's above 0.7.

Prints a table, writes JSON, exits 1 when a check fails. Figures on another machine or under load
differ in time, not in outcome: every check is seeded.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from benchmarks.output import write_json
from mjx_push import xla

HELD_OUT_SEED = 12345  # the toy's evaluation episodes that best-model selection never saw


def _optimised(on: bool) -> None:
    """Compile with XLA's optimisations or most of them off: the toy checks' time is compilation (as in
    the tests), the scene check's is execution."""
    import jax

    jax.config.update("jax_disable_most_optimizations", not on)


def toy(kind: str) -> dict:
    import jax
    import jax.numpy as jnp

    from mjx_push.train.loop import Runner, make_train, train as run_train
    from tests.toy import TAU, make_toy, toy_config

    _optimised(False)
    steps = {"vpm": 1600, "ugru": 1920}[kind]
    cfg = toy_config(kind, steps)
    adapter = make_toy(success_tau=TAU)
    runner = Runner(make_train(cfg, adapter))
    untrained = jax.tree.map(jnp.copy, runner.trainer.init(jax.random.PRNGKey(0)).sac.actor_params)
    state, history = run_train(jax.random.PRNGKey(0), cfg, adapter, runner=runner)
    held_out = jax.random.PRNGKey(HELD_OUT_SEED)
    keys = ("success_rate", "mean_reward", "start_distance", "final_distance")
    before, after = (
        {k: float(r[k]) for k in keys}
        for r in (runner.evaluate(untrained, held_out), runner.evaluate(state.best_actor_params, held_out))
    )
    checks = {
        "untrained success < 0.2 (not solved by chance)": before["success_rate"] < 0.2,
        "last in-run success >= 0.9": history[-1]["eval/success_rate"] >= 0.9,
        "held-out success of the kept actor >= 0.9": after["success_rate"] >= 0.9,
        "mean reward up by > 3": after["mean_reward"] > before["mean_reward"] + 3.0,
        "final distance < radius and < half the untrained one": after["final_distance"]
        < min(TAU, 0.5 * before["final_distance"]),
        "the same held-out starts": abs(after["start_distance"] - before["start_distance"])
        <= 1e-6 * before["start_distance"],
    }
    figure = f"held-out success {before['success_rate']:.2f} -> {after['success_rate']:.2f} at {steps} env steps"
    return {"figure": figure, "checks": checks, "before": before, "after": after, "env_steps": steps}


def toy_all_features() -> dict:
    import jax

    from mjx_push.train.loop import train as run_train
    from tests.toy import TAU, all_features_config, make_toy

    _optimised(False)
    cfg = all_features_config()
    _, history = run_train(jax.random.PRNGKey(0), cfg, make_toy(success_tau=TAU))
    last = float(history[-1]["eval/success_rate"])
    return {
        "figure": f"in-run success {last:.2f} at {cfg.loop.total_env_steps} env steps",
        "checks": {"last in-run success >= 0.9": last >= 0.9},
        "success": last,
        "env_steps": cfg.loop.total_env_steps,
    }


def toy_two_processes() -> dict:
    import tempfile

    from tests import two_processes
    from tests.toy import toy_config

    steps = 1600
    cfg = two_processes.toy_run(toy_config("vpm", steps, data_parallel=2))
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        two_processes.launch(run_dir, two_processes.write_config(Path(tmp) / "config.json", cfg))
        first, second = two_processes.summaries(run_dir)
    best = float(first["best_eval_success_rate"])
    return {
        "figure": f"best in-run success {best:.2f} at {steps} env steps, 2 processes",
        "checks": {
            "both processes ran as one run of 2 devices": all(
                s["devices"] == 2 and s["processes"] == 2 and s["env_steps"] == steps for s in (first, second)
            ),
            "the same result in both processes": second["best_eval_success_rate"] == first["best_eval_success_rate"],
            "best in-run success >= 0.9": best >= 0.9,
        },
        "success": best,
        "env_steps": steps,
    }


def scene_imitation() -> dict:
    import jax
    import jax.numpy as jnp

    from mjx_push import encoder as enc
    from mjx_push.train import presets
    from mjx_push.train.config import LoopConfig
    from mjx_push.train.loop import Runner, make_train
    from mjx_push.train.push_task import make_push_adapter

    _optimised(True)
    base = presets.make("vpm", "cpu")
    T = 10  # the approach: the rod travels round the object to the push point
    # One cylinder (size, mass, friction fixed; start and goal drawn as in the task): a mapping from
    # latents to pushes that a few dozen episodes can teach.
    one = dataclasses.replace(
        base.env.objects,
        shape="cylinder",
        radius=(0.05, 0.05),
        min_height=0.05,
        max_height_cylinder=0.05,
        mass=(0.2, 0.2),
        friction=(0.5, 0.5),
    )
    env = dataclasses.replace(base.env, episode_length=T, objects=one)
    t = dataclasses.replace(
        base.train,
        # A narrower critic than the preset's: the actor learns from the labels.
        agent=dataclasses.replace(base.train.agent, critic_hidden=(128, 128)),
        sac=dataclasses.replace(base.train.sac, batch_size=128, bc_batch_size=128, bc_weight=4.0, q_filter=False),
        replay=dataclasses.replace(base.train.replay, capacity_transitions=20_000),
        loop=LoopConfig(
            num_envs=16,
            total_env_steps=16 * T * 10,
            warmup_env_steps=16 * T,
            utd=0.5,
            eval_every_env_steps=16 * T * 10,
            eval_episodes=16,
        ),
        demo=dataclasses.replace(base.train.demo, label_all=True, fraction=1.0),
    )
    cfg = dataclasses.replace(base, env=env, train=t, encoder=None)
    runner = Runner(make_train(cfg.train, make_push_adapter(cfg.env, enc.load(None), expert_config=cfg.expert)))
    state = runner.trainer.init(jax.random.PRNGKey(0))
    untrained = jax.tree.map(jnp.copy, state.sac.actor_params)
    history = []
    for _ in range(t.loop.num_iterations(T)):
        state, m = runner.iteration(state)
        history.append(m)
    bc = [float(m["sac/bc_loss"]) for m in history if bool(m["learning"])]

    # Fresh episodes driven by the expert (held out): how far is each actor from its labels?
    episodes, _ = runner.rollout(
        state.sac.actor_params, jax.random.PRNGKey(99), jnp.asarray(False), jnp.asarray(True), jnp.ones(16, bool)
    )
    nets = runner.trainer.networks
    idx = jnp.tile(jnp.arange(T)[None], (16, 1))
    labels = episodes["expert_action"].reshape(-1, 3)

    def error(actor):
        a = nets.deterministic_action(actor, episodes, idx)
        return float(jnp.mean(jnp.sum((a - episodes["expert_action"]) ** 2, -1)))

    def direction(actor):  # mean cosine between the actor's and the expert's flange moves
        a = nets.deterministic_action(actor, episodes, idx)[..., :2].reshape(-1, 2)
        e = labels[:, :2]
        return float(jnp.mean(jnp.sum(a * e, -1) / (jnp.linalg.norm(a, axis=-1) * jnp.linalg.norm(e, axis=-1) + 1e-6)))

    before, after = error(untrained), error(state.sac.actor_params)
    constant = float(jnp.mean(jnp.sum((labels - labels.mean(0)) ** 2, -1)))  # the best state-blind actor
    cos_before, cos_after = direction(untrained), direction(state.sac.actor_params)
    checks = {
        "cloning loss falls below 0.6 of its first value": bc[-1] < 0.6 * bc[0],
        "held-out error < 0.6 x the best constant's < 0.6 x the untrained's": after < 0.6 * constant < 0.6 * before,
        "direction cosine > 0.7 and up by > 0.5": cos_after > 0.7 and cos_after > cos_before + 0.5,
    }
    figure = (
        f"squared error {before:.3f} -> {after:.3f} (best constant {constant:.3f}); "
        f"cosine {cos_before:.2f} -> {cos_after:.2f}"
    )
    return {
        "figure": figure,
        "checks": checks,
        "error": {"untrained": before, "constant": constant, "trained": after},
        "cosine": {"untrained": cos_before, "trained": cos_after},
        "bc_loss": bc,
        "env_steps": t.loop.total_env_steps,
    }


def expert_1cm() -> dict:
    import numpy as np

    from mjx_push.train import presets
    from mjx_push.train.episodes import EvalSpec
    from mjx_push.train.evaluate import ExpertPolicy, evaluate

    _optimised(False)  # as the suite compiled it: its time is compilation
    res = evaluate(
        ExpertPolicy(presets.make("vpm", "cpu")), EvalSpec(setting="standard", shape="all", episodes=8, batch=4)
    )
    per = res["per_episode"]
    final, start = per["final_distance"], per["start_distance"]
    checks = {
        "no invalid episode": res["invalid_episodes"] == 0,
        "every episode within 1 cm": bool(np.all(final < 0.01)),
        "every object travelled (ends under half its start distance)": bool(np.all(final < 0.5 * start)),
    }
    figure = f"{int(np.sum(final < 0.01))} / {len(final)} within 1 cm, worst {100 * float(final.max()):.2f} cm"
    return {"figure": figure, "checks": checks, "final_distance_m": [round(float(x), 5) for x in final]}


CHECKS = {
    "toy-vpm": lambda: toy("vpm"),
    "toy-ugru": lambda: toy("ugru"),
    "toy-all-features": toy_all_features,
    "toy-two-processes": toy_two_processes,
    "expert-1cm": expert_1cm,
    "scene-imitation": scene_imitation,
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="+", choices=list(CHECKS), default=list(CHECKS), metavar="CHECK")
    ap.add_argument("--out", type=Path, default=Path("outputs/learning_checks.json"))
    args = ap.parse_args(argv)
    xla.use_cpu_devices()
    from rich.console import Console
    from rich.table import Table

    rows = []
    for name in args.only:
        t0 = time.perf_counter()
        row = {"check": name, **CHECKS[name]()}
        row["seconds"] = round(time.perf_counter() - t0, 1)
        row["passed"] = all(row["checks"].values())
        rows.append(row)
        failed = [what for what, ok in row["checks"].items() if not ok]
        print(f"{name}: {'passed' if row['passed'] else 'FAILED: ' + '; '.join(failed)} ({row['seconds']} s)")
    table = Table(title="Learning checks")
    for col in ("check", "result", "figure", "s"):
        table.add_column(col)
    for r in rows:
        table.add_row(r["check"], "passed" if r["passed"] else "FAILED", r["figure"], f"{r['seconds']:.0f}")
    Console(width=160).print(table)
    write_json(args.out, {"checks": rows, "passed": all(r["passed"] for r in rows)})
    return 0 if all(r["passed"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
