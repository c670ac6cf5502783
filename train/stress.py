"""The stress suite: a policy (or the scripted expert) on the protocol's episodes under what a real
robot cell brings (docs/robustness.md).

Every row of `mjx_push.perturb.SUITE` (masks, camera, latency, flange noise, the arm's velocity
tracking, the object's mass and friction, the push rod) at each level (mild, realistic, severe), an
"all" row with every row at once, the clean row and the noise floor (the clean episodes with the
observation noise redrawn: how far sub-millimetre chaos alone moves success), per shape. Episode i of
a shape is the evaluation protocol's (`mjx_push.train.episodes.episode_objects`: the same object,
start, goal and noise key as `mjx-push eval` gives it) and meets the same random draws (camera
direction, signs, pixel noise) in every cell, so a row's drop from clean is a paired difference.

One compiled environment per geom type runs every cell: it is built with every row's perturbation, and
each episode gets its own record (`mjx_push.perturb.draw_episode`); the neutral record of the clean
row changes nothing, bit for bit (tests/test_stress.py), so the clean row is the clean evaluation's
episodes.

Per cell and shape: success within `success_tau` with a 95 % Wilson interval, the drop from clean with
a 95 % interval over the paired episodes (normal approximation), the final object-goal distance
(median, 75th and 90th percentiles, mean). The robustness score is the mean success over the suite's
rows at the realistic level (each row the mean over shapes; the "all" row and the noise floor apart).
The scripted expert reads the simulator's ground truth, so only the physical rows (`perturb.PHYSICAL`)
reach it: its other rows are its clean row, by construction, and are not simulated.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjx_push import devices, perturb
from mjx_push import encoder as enc
from mjx_push import expert as expert_mod
from mjx_push.env import EnvConfig, PushEnv
from mjx_push.errors import ConfigError
from mjx_push.perturb import LEVELS, SUITE, PerturbConfig
from mjx_push.train.episodes import EvalSpec, episode_objects
from mjx_push.train.networks import make_networks

FORMAT = "mjx-push-stress"
VERSION = 1
PARTIAL_FORMAT = "mjx-push-stress-partial"
ALL = "all"  # every row of the suite at once
# The clean episodes with the observation noise (0.1 mm on the flange) redrawn: the simulation is
# chaotic at that scale (docs/parity.md), so this row's drop is the floor under every other row's.
NOISE_FLOOR = "noise_floor"
SHAPES = ("cylinder", "square", "rectangular", "cuboid")
PROTOCOL_TEST_SEED = 7_001_009  # docs/comparison-protocol.md: the test episodes
_PERTURB_STREAM = 2  # episode key -> perturbation uniforms (0 and 1 are the object and the noise keys)
_REDRAW = 1  # noise key -> the noise floor's
Z95 = 1.959963984540054


@dataclasses.dataclass(frozen=True)
class StressConfig:
    perturbations: tuple[str, ...] = (*SUITE, ALL)
    levels: tuple[str, ...] = LEVELS
    shapes: tuple[str, ...] = ("cylinder", "square", "rectangular")
    setting: str = "difficult"  # the protocol's setting (mjx_push.train.episodes.SETTINGS)
    episodes: int = 50  # per cell and shape
    seed: int = PROTOCOL_TEST_SEED
    # Environments simulated at once. It does not change the episodes, but their sub-millimetre outcomes
    # depend on the compiled batch (docs/robustness.md): compare runs at one batch; batch = episodes
    # keeps every cell's episode i at the same place in its batch.
    batch: int = 50
    success_tau: float | None = None  # None: the radius the policy trained for

    def __post_init__(self):
        for name in self.perturbations:
            if name not in SUITE and name != ALL:
                raise ConfigError(f"perturbations must be among {(*SUITE, ALL)}, got {name!r}")
        for level in self.levels:
            if level not in LEVELS:
                raise ConfigError(f"levels must be among {LEVELS}, got {level!r}")
        for shape in self.shapes:
            if shape not in SHAPES:
                raise ConfigError(f"shapes must be among {SHAPES}, got {shape!r}")
        for name in ("perturbations", "levels", "shapes"):
            v = getattr(self, name)
            if len(set(v)) != len(v) or (name != "perturbations" and not v):
                raise ConfigError(f"{name} must list distinct values (at least one), got {v!r}")
        for name in ("episodes", "batch"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"{name} must be a positive integer, got {v!r}")
        # The setting's own checks (EvalSpec's messages name it).
        EvalSpec(setting=self.setting, episodes=self.episodes, seed=self.seed, success_tau=self.success_tau)

    def cells(self) -> list[tuple[str, str | None, PerturbConfig]]:
        """(row, level, perturbations) of every cell: the clean one first, then the noise floor."""
        out = [("clean", None, PerturbConfig()), (NOISE_FLOOR, None, PerturbConfig())]
        for name in self.perturbations:
            rows = tuple(n for n in SUITE if n != "mask_erode") if name == ALL else (name,)
            out += [(name, level, perturb.suite_config(rows, level)) for level in self.levels]
        return out


# --- statistics ----------------------------------------------------------------------------------------
def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a proportion (sound at 0 % and 100 %, unlike the normal one)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def paired_drop(clean: np.ndarray, perturbed: np.ndarray) -> dict:
    """Clean minus perturbed success over the same episodes, with a 95 % normal interval."""
    d = np.asarray(clean, np.float64) - np.asarray(perturbed, np.float64)
    half = Z95 * float(np.std(d, ddof=1)) / math.sqrt(len(d)) if len(d) > 1 else 0.0
    mean = float(np.mean(d))
    return {"mean": mean, "ci95": [mean - half, mean + half]}


def _cell_stats(success: np.ndarray, final: np.ndarray, invalid: np.ndarray, clean: np.ndarray) -> dict:
    n, k = len(success), int(np.sum(success))
    q = np.percentile(final, [50, 75, 90])
    return {
        "success": k / n,
        "ci95": list(wilson(k, n)),
        "n": n,
        "drop": paired_drop(clean, success),
        "final_distance": {"p50": float(q[0]), "p75": float(q[1]), "p90": float(q[2]), "mean": float(np.mean(final))},
        "invalid": int(np.sum(invalid)),
        "per_episode": {"success": [int(x) for x in success], "final_distance": [round(float(x), 6) for x in final]},
    }


# --- compiled episode pieces (shared by every cell, and by the tests) ------------------------------------
@functools.lru_cache(maxsize=8)
def runner(env_config: EnvConfig, geom_type: str, batch: int):
    """(env, reset, step) of a batch of `batch` environments of `geom_type` under `env_config`:
    `reset(keys, params, records)` and `step(state, actions)`, jitted and split over the devices."""
    env = PushEnv(env_config, geom_type)
    mesh = devices.env_mesh((batch,))
    reset = jax.vmap(env.reset_with) if env.perturbed else jax.vmap(lambda k, p, _: env.reset_with(k, p))
    return env, jax.jit(devices.shard(reset, mesh)), jax.jit(devices.shard(jax.vmap(env.step), mesh))


@functools.lru_cache(maxsize=8)
def _policy_step(agent_config):
    nets = make_networks(agent_config)

    def step(actor_params, encoder_params, carry, obs, z_goal):
        o = {"ee_xy": obs["ee_xy"], "z_obj": enc.encode(encoder_params, obs["object_mask"]), "z_goal": z_goal}
        return nets.act(actor_params, carry, o, jax.random.PRNGKey(0), True)

    return nets, jax.jit(step), jax.jit(enc.encode)


@functools.lru_cache(maxsize=8)
def _expert_step(expert_config, env_config: EnvConfig, is_box: bool):
    def step(info, size):
        gt = expert_mod.ground_truth(info, size, jnp.full(size.shape[0], is_box))
        return jax.vmap(lambda g: expert_mod.act(expert_config, env_config, g))(gt)

    return jax.jit(step)


def is_expert(policy) -> bool:
    """Whether `policy` is the scripted expert (`mjx_push.train.evaluate.ExpertPolicy`, which carries no
    actor), told apart without importing the evaluator (a sibling of this module)."""
    return getattr(policy, "actor_params", None) is None


def run_episodes(policy, env_config: EnvConfig, geom_type: str, batch: int, params, keys, records) -> dict:
    """Whole episodes of `policy` (a `Policy` or an `ExpertPolicy`) for one batch: object `params`,
    environment `keys` and perturbation `records` with a leading axis of `batch`. Returns per-episode
    NumPy arrays: success, final_distance (the start distance for an invalid episode), invalid."""
    env, reset, step = runner(env_config, geom_type, batch)
    s = reset(keys, params, records)
    if is_expert(policy):
        act = _expert_step(policy.config.expert, env.config, geom_type == "box")
        policy_fn = lambda s, carry: (act(s.info, s.info["params"].size), carry)  # noqa: E731
        carry = None
    else:
        nets, act, encode = _policy_step(policy.config.train.agent)
        z_goal = encode(policy.encoder_params, s.info["goal_mask"])
        carry = nets.init_carry(batch)

        def policy_fn(s, carry):
            return act(policy.actor_params, policy.encoder_params, carry, s.obs, z_goal)

    for _ in range(env.config.episode_length):
        action, carry = policy_fn(s, carry)
        s = step(s, action)
    s = jax.device_get(s)
    dist = np.linalg.norm(s.info["object_xy"] - s.info["goal_xy"], axis=-1)
    start = np.linalg.norm(np.asarray(params.start)[:, :2] - np.asarray(params.goal)[:, :2], axis=-1)
    invalid = np.asarray(s.info["episode_invalid"])
    return {
        "success": ~invalid & (dist < env.config.success_tau),
        "final_distance": np.where(invalid, start, dist),
        "invalid": invalid,
    }


def _geom_type(shape: str) -> str:
    return "cylinder" if shape == "cylinder" else "box"


def env_config(policy_env: EnvConfig, cfg: StressConfig, geom_type: str) -> EnvConfig:
    """The environment the suite runs `geom_type` in: the policy's task, evaluation objects (uniform
    sampling, one geom type), and the code of every row of the suite at the largest requested level
    (so a policy and the expert, any rows, share one compiled environment per level set)."""
    level = max(cfg.levels, key=LEVELS.index)
    rows = [perturb.suite_config([n], level) for n in SUITE]
    env = dataclasses.replace(
        policy_env,
        objects=dataclasses.replace(
            policy_env.objects, mode="uniform", shape="cylinder" if geom_type == "cylinder" else "cuboid"
        ),
        perturb=functools.reduce(PerturbConfig.merge, rows, PerturbConfig()),
    )
    if cfg.success_tau is not None:
        env = dataclasses.replace(env, success_tau=cfg.success_tau)
    return env


def shape_episodes(cfg: StressConfig, env: EnvConfig, shape: str):
    """(ObjectParams, environment keys) of the protocol's episodes 0 .. cfg.episodes - 1 of `shape`, as
    NumPy arrays."""
    spec = EvalSpec(setting=cfg.setting, shape=shape, episodes=cfg.episodes, seed=cfg.seed)
    return jax.device_get(episode_objects(spec, env.objects, _geom_type(shape), np.arange(cfg.episodes)))


def pad(params, keys, records, batch: int):
    """Each of the three trees cut or padded (the last entry repeated) to `batch` along its first axis:
    one compiled batch size for every chunk."""

    def fit(x):
        x = np.asarray(x)
        return np.concatenate([x, np.repeat(x[-1:], batch - len(x), axis=0)])[:batch]

    return tuple(jax.tree.map(fit, t) for t in (params, keys, records))


def episode_uniforms(seed: int, indices: np.ndarray) -> np.ndarray:
    """(len(indices), N_UNIFORMS) uniforms of episodes `indices`: every cell turns the same ones into its
    record, so a camera offset points the same way at every level."""
    base = jax.random.PRNGKey(seed)
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(base, i), _PERTURB_STREAM))(jnp.asarray(indices))
    return np.asarray(jax.vmap(lambda k: jax.random.uniform(k, (perturb.N_UNIFORMS,)))(keys), np.float64)


# --- resuming ------------------------------------------------------------------------------------------
@functools.cache
def _code_and_machine() -> str:
    """The package's source, the versions of what simulates and compiles, and the device layout the
    batches are split over: sub-millimetre outcomes depend on all of them (docs/parity.md)."""
    import importlib.metadata as md

    import mjx_push

    h = hashlib.sha256()
    for root in {Path(mjx_push.__file__).parent, Path(__file__).parent}:  # the scene and the learner
        for f in sorted(root.rglob("*.py")):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    for pkg in ("jax", "jaxlib", "mujoco", "mujoco-mjx"):
        h.update(f"{pkg}={md.version(pkg)}".encode())
    h.update(f"{jax.default_backend()} {[d.device_kind for d in jax.devices()]}".encode())
    return h.hexdigest()


def fingerprint(policy, cfg: StressConfig) -> str:
    """What a stress run's episodes depend on: the policy's weights and configuration (the expert's
    settings for the expert), the suite's settings, the code, the packages and the devices. A partial
    file resumes only a run with the same."""
    h = hashlib.sha256()
    h.update(f"{VERSION} {_code_and_machine()}".encode())
    h.update(json.dumps(dataclasses.asdict(cfg), sort_keys=True).encode())
    h.update(repr(policy.config).encode())
    for tree in (policy.actor_params, policy.encoder_params):
        for leaf in jax.tree.leaves(jax.device_get(tree)):
            a = np.ascontiguousarray(leaf)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
    return h.hexdigest()


class Partial:
    """The chunks of a stress run finished so far, in a JSON file rewritten (atomically) after each: a
    run stopped by a session's end, a kill or a crash reruns with the same file and simulates only the
    chunks it lacks. Each chunk's episodes are the same whichever run simulates them (the same
    compiled batch and inputs), so a resumed run's record equals an uninterrupted one's."""

    def __init__(self, path: Path, key: str):
        self.path, self.key = Path(path), key
        self.chunks: dict[str, dict] = {}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
            except (OSError, ValueError) as e:
                raise ConfigError(f"{self.path}: not a readable stress partial file ({e}); move it away") from e
            if not isinstance(data, dict) or data.get("format") != PARTIAL_FORMAT or "chunks" not in data:
                raise ConfigError(f"{self.path}: not a stress partial file; move it away")
            if data.get("key") != key:
                raise ConfigError(
                    f"{self.path} holds a stress run of another policy or other settings (or code, packages, "
                    "devices): rerun that run's command to finish it, or start over (`--fresh`, or move the file)"
                )
            self.chunks = data["chunks"]

    def episodes(self) -> int:
        return sum(len(c["success"]) for c in self.chunks.values())

    def get(self, name: str) -> dict | None:
        c = self.chunks.get(name)
        if c is None:
            return None
        return {
            "success": np.asarray(c["success"], bool),
            "final_distance": np.asarray(c["final_distance"], np.float32),
            "invalid": np.asarray(c["invalid"], bool),
        }

    def put(self, name: str, r: dict) -> None:
        self.chunks[name] = {
            "success": [bool(x) for x in r["success"]],
            "final_distance": [float(x) for x in r["final_distance"]],  # float32 -> float64: exact
            "invalid": [bool(x) for x in r["invalid"]],
        }
        tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"format": PARTIAL_FORMAT, "key": self.key, "chunks": self.chunks}))
        os.replace(tmp, self.path)


def partial_path(out: Path) -> Path:
    """Where a stress run writing `out` keeps its finished chunks until it ends."""
    out = Path(out)
    return out.with_name(out.name + ".partial")


def stress(
    policy,
    cfg: StressConfig = StressConfig(),
    progress: Callable[[str], None] | None = None,
    resume_from: Path | None = None,
) -> dict:
    """Run the suite on `policy` (a `mjx_push.train.runs.policies.Policy` or a
    `mjx_push.train.evaluate.ExpertPolicy`). Returns a JSON-able record (`format_table` prints it).
    With `resume_from`, the chunks finished so far are kept in that file (`Partial`) and a rerun with
    the same file simulates only what is missing (the caller removes it once the record is saved)."""
    t0 = time.perf_counter()
    partial = None if resume_from is None else Partial(resume_from, fingerprint(policy, cfg))
    resumed = 0 if partial is None else partial.episodes()
    expert = is_expert(policy)
    cells = cfg.cells()
    skipped = {}
    for i, (name, level, _) in enumerate(cells):
        if expert and name not in perturb.PHYSICAL and name not in ("clean", ALL):
            skipped[i] = "the scripted expert reads ground truth: this row is its clean row"
    # Identical cells (e.g. the reference's 3 x 3 open-close at two levels) run once.
    first: dict[tuple, int] = {}
    same_as = {}
    for i, (name, _, pc) in enumerate(cells):
        if i not in skipped:
            same_as[i] = first.setdefault((pc, name == NOISE_FLOOR), i)
    to_run = sorted(set(same_as.values()))

    idx = np.arange(cfg.episodes)
    uniforms = episode_uniforms(cfg.seed, idx)
    out: dict[tuple[int, str], dict] = {}
    total, done = len(to_run) * len(cfg.shapes) * cfg.episodes, 0
    for shape in cfg.shapes:
        geom = _geom_type(shape)
        env = env_config(policy.config.env, cfg, geom)
        params, keys = shape_episodes(cfg, env, shape)
        redrawn = np.asarray(jax.vmap(lambda k: jax.random.fold_in(k, _REDRAW))(keys))
        jobs = [(c, e) for c in to_run for e in idx]  # cells x episodes, in chunks of the batch
        results: dict[str, list] = {"success": [], "final_distance": [], "invalid": []}
        for start in range(0, len(jobs), cfg.batch):
            chunk = jobs[start : start + cfg.batch]
            ep = np.array([e for _, e in chunk])
            name = f"{shape}/{start}"
            r = None if partial is None else partial.get(name)
            if r is None:  # a chunk the partial file lacks: draw its inputs and simulate it
                records = [perturb.draw_episode(cells[c][2], uniforms[e]) for c, e in chunk]
                records = jax.tree.map(lambda *xs: np.stack(xs), *records)
                env_keys = np.stack([(redrawn if cells[c][0] == NOISE_FLOOR else keys)[e] for c, e in chunk])
                batch_in = pad(jax.tree.map(lambda a: a[ep], params), env_keys, records, cfg.batch)
                r = {k: v[: len(chunk)] for k, v in run_episodes(policy, env, geom, cfg.batch, *batch_in).items()}
                if partial is not None:
                    partial.put(name, r)
            for k in results:
                results[k].append(r[k])
            done += len(chunk)
            if progress is not None:
                progress(f"{shape}: {done}/{total} episodes, {time.perf_counter() - t0:.0f} s")
        arrays = {k: np.concatenate(v) for k, v in results.items()}
        for j, c in enumerate(to_run):
            sl = slice(j * cfg.episodes, (j + 1) * cfg.episodes)
            out[(c, shape)] = {k: v[sl] for k, v in arrays.items()}
    tau = env.success_tau

    rows = []
    clean = {shape: out[(0, shape)]["success"] for shape in cfg.shapes}
    for i, (name, level, pc) in enumerate(cells):
        src = 0 if i in skipped else same_as[i]
        shapes = {}
        for shape in cfg.shapes:
            r = out[(src, shape)]
            shapes[shape] = _cell_stats(r["success"], r["final_distance"], r["invalid"], clean[shape])
        rows.append(
            {
                "perturbation": name,
                "level": level,
                "fields": {f: getattr(pc, f) for f in perturb.FIELDS if f in pc.active()},
                "shapes": shapes,
                "mean": {
                    "success": float(np.mean([s["success"] for s in shapes.values()])),
                    "drop": float(np.mean([s["drop"]["mean"] for s in shapes.values()])),
                },
                "skipped": skipped.get(i),
            }
        )
    realistic = [r["mean"]["success"] for r in rows if r["level"] == "realistic" and r["perturbation"] in SUITE]
    clean_mean = rows[0]["mean"]["success"]
    score = float(np.mean(realistic)) if realistic else None
    result = {
        "format": FORMAT,
        "version": VERSION,
        "policy": "expert" if expert else policy.config.agent,
        "config": {**dataclasses.asdict(cfg), "success_tau": tau},
        "suite": {n: {f: list(v) for f, v in fields.items()} for n, fields in SUITE.items()},
        "rows": rows,
        "score": {
            "realistic": score,
            "clean": clean_mean,
            "drop": None if score is None else clean_mean - score,
            "rows": len(realistic),
        },
        # Of this process alone: a resumed run's earlier chunks ran before it (`resumed_episodes` of them).
        "wall_s": time.perf_counter() - t0,
        "resumed_episodes": resumed,
    }
    return result


# --- tables -------------------------------------------------------------------------------------------
def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}"


def _fields(fields: dict) -> str:
    parts = []
    for f, v in fields.items():
        if f == "camera_yaw":
            parts.append(f"yaw {math.degrees(v):.1f} deg")
        elif f in ("camera_shift", "flange_noise", "rod_radius", "rod_length"):
            parts.append(f"{f} {1000 * v:g} mm")
        elif f == "latency" or f == "velocity_lag":
            parts.append(f"{f} {v:g} ms")
        else:
            parts.append(f"{f} {v:g}")
    return ", ".join(parts)


def format_table(result: dict) -> str:
    """A Markdown table of one `stress` record: success within the radius (%) per shape, its mean, the
    drop from clean (points, 95 % interval) and the final distance's median and 90th percentile (mm)."""
    shapes = list(result["config"]["shapes"])
    head = ["perturbation", "level", "setting", *shapes, "mean", "drop (95% CI)", "final p50 / p90 (mm)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in result["rows"]:
        cells = [r["perturbation"], r["level"] or "", _fields(r["fields"])]
        cells += [_pct(r["shapes"][s]["success"]) for s in shapes]
        cells.append(_pct(r["mean"]["success"]))
        if r["perturbation"] == "clean":
            cells.append("")
        else:
            lo = np.mean([r["shapes"][s]["drop"]["ci95"][0] for s in shapes])
            hi = np.mean([r["shapes"][s]["drop"]["ci95"][1] for s in shapes])
            cells.append(f"{100 * r['mean']['drop']:+.0f} ({100 * lo:+.0f}, {100 * hi:+.0f})")
        p50 = np.median([r["shapes"][s]["final_distance"]["p50"] for s in shapes])
        p90 = np.median([r["shapes"][s]["final_distance"]["p90"] for s in shapes])
        cells.append(f"{1000 * p50:.1f} / {1000 * p90:.1f}")
        if r["skipped"]:
            cells[3:] = ["= clean"] * (len(cells) - 3)
        lines.append("| " + " | ".join(cells) + " |")
    s = result["score"]
    tau = result["config"]["success_tau"]
    lines.append("")
    lines.append(
        f"{result['policy']}: robustness score {_pct(s['realistic'])} % within {100 * tau:g} cm (mean success over "
        f"{s['rows']} rows at the realistic level), clean {_pct(s['clean'])} %; {result['config']['episodes']} "
        f"episodes per cell and shape, seed {result['config']['seed']}."
    )
    return "\n".join(lines)


def format_summary(results: list[dict]) -> str:
    """A Markdown table of several `stress` records (shipped policies, the expert): clean success, the
    noise floor's, the robustness score and each row's success at the realistic level (mean over
    shapes, %)."""
    names = [n for n in SUITE if any(r["perturbation"] == n for res in results for r in res["rows"])]
    head = ["policy", "clean", "noise floor", "score", *names]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for res in results:
        at = {r["perturbation"]: r for r in res["rows"] if r["level"] == "realistic"}
        floor_row = next(r for r in res["rows"] if r["perturbation"] == NOISE_FLOOR)
        floor = None if floor_row["skipped"] else floor_row["mean"]["success"]
        # The expert's rows that cannot reach it (it reads ground truth) are its clean row by
        # construction: shown as "=", and its score is over the rows it meets.
        met = [at[n]["mean"]["success"] for n in names if n in at and not at[n]["skipped"]]
        score = _pct(res["score"]["realistic"])
        if any(at[n]["skipped"] for n in names if n in at):
            score = f"{_pct(float(np.mean(met)) if met else None)} (rows it meets)"
        cells = [res["policy"], _pct(res["score"]["clean"]), _pct(floor), score]
        cells += [("=" if at[n]["skipped"] else _pct(at[n]["mean"]["success"])) if n in at else "-" for n in names]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
