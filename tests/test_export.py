"""Exported policies (mjx_push.export.policy_file, mjx_push.export.numpy_policy, mjx_push.export.torch_policy), the export / deploy
commands (mjx_push.cli) and the evaluation metrics (mjx_push.export.metrics). Networks are random-initialised, never
trained: the point is that every implementation computes the same function."""

import importlib.metadata
import importlib.util
import json
import math
import subprocess
import sys
import zipfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjx_push.export import policy_file as pfile
from mjx_push.cli import Deploy, Export
from mjx_push.export.metrics import summarize_records
from mjx_push.export.numpy_policy import NumpyPolicy, decode_substeps
from mjx_push import encoder as enc
from mjx_push import mask_geometry, scene
from mjx_push.env import EnvConfig
from mjx_push.env import decode_substeps as jax_decode_substeps
from mjx_push.train.config import AGENT_KINDS
from mjx_push.train.networks import make_networks
from mjx_push.train.presets import make
from mjx_push.train.runs.policies import Policy, save_policy
from tests.helpers import a_s_for

REPO = Path(__file__).resolve().parents[1]
HAVE_TORCH = importlib.util.find_spec("torch") is not None
NO_TORCH = "torch is not installed (optional extra: pip install -e '.[torch]')"
# Random-init heads give actions of a few 1e-2; a larger mean head spreads them over [-1, 1] so the
# flange really moves, the object gets pushed and the masks change during the episode.
HEAD_GAIN = 25.0
ATOL = 1e-5


def _randomize_biases(tree, rng: np.random.Generator):
    """flax initialises biases at zero, which would hide a misplaced bias (e.g. the GRU's hn bias)."""
    return jax.tree_util.tree_map_with_path(
        lambda path, v: (
            v + 0.1 * rng.standard_normal(v.shape).astype(np.float32) if getattr(path[-1], "key", None) == "bias" else v
        ),
        tree,
    )


# uGRU as the reference preset trains it (no input normalisation); the others as the measured presets
# do, with statistics far from (0, 1) so that a reader that skipped or misapplied them would differ.
PRESET = {"vpm": "smoke", "stacked": "smoke", "ugru": "reference", "egru": "smoke"}


def _policy(kind: str, encoder_params, seed: int) -> tuple[Policy, object]:
    cfg = make(kind, PRESET[kind])
    nets = make_networks(cfg.train.agent)
    actor = nets.init_actor(jax.random.PRNGKey(seed), 50)
    rng = np.random.default_rng(seed)
    actor = _randomize_biases(actor, rng)
    head = actor["params"]["mean_head"]
    actor["params"]["mean_head"] = {k: v * HEAD_GAIN for k, v in head.items()}
    assert ("norm" in actor) == cfg.train.agent.obs_norm
    if cfg.train.agent.obs_norm:
        actor["norm"] = {
            "norm": {
                "ee_xy_mean": jnp.asarray(scene.home_flange_pos()[:2] + 0.01, jnp.float32),
                "ee_xy_std": jnp.asarray([0.05, 0.08], jnp.float32),
                "z_mean": jnp.asarray(rng.normal(size=6), jnp.float32),
                "z_std": jnp.asarray(rng.uniform(0.2, 3.0, 6), jnp.float32),
            }
        }
    scores = {"best_eval_mean_reward": -42.0, "best_eval_success_rate": float("nan")}
    return Policy(cfg, actor, encoder_params, scores), nets


@pytest.fixture(scope="module")
def encoder_params():
    """A random encoder with the trained encoder's structure. Drawn in NumPy (LeCun-normal kernels, random
    biases): flax's init of the whole VAE compiles the decoder too and takes ~15 s on 2 cores."""
    rng = np.random.default_rng(7)
    template = enc._template()

    def draw(path, leaf):
        if getattr(path[-1], "key", None) == "bias":
            return jnp.asarray(0.1 * rng.standard_normal(leaf.shape), jnp.float32)
        fan_in = int(np.prod(leaf.shape[:-1]))
        return jnp.asarray(rng.standard_normal(leaf.shape) / np.sqrt(fan_in), jnp.float32)

    return jax.tree_util.tree_map_with_path(draw, template)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, encoder_params):
    """kind -> (Policy, Networks, path of the exported .npz)."""
    root = tmp_path_factory.mktemp("export")
    out = {}
    for i, kind in enumerate(AGENT_KINDS):
        policy, nets = _policy(kind, encoder_params, seed=i)
        path = root / f"{kind}.npz"
        pfile.export_policy(policy, path)
        out[kind] = (policy, nets, path)
    return out


@pytest.fixture(scope="module", autouse=True)
def _torch_single_thread():
    # One sample per step: torch's intra-op threads only add latency (120 ms vs 2 ms per step measured on
    # a loaded 2-core machine).
    if HAVE_TORCH:
        import torch

        before = torch.get_num_threads()
        torch.set_num_threads(1)
        yield
        torch.set_num_threads(before)
    else:
        yield


@pytest.fixture(scope="module")
def jax_encode():
    return jax.jit(enc.encode)


# --- parity with the JAX policy over a whole episode ---------------------------------------------------
def _moving_object(geom: str, seed: int, steps: int = 51):
    """Masks (steps, 64, 64) of an object sliding and turning across the view, and its goal mask."""
    rng = np.random.default_rng(seed)
    home = scene.home_flange_pos()[:2]
    start, goal = home + rng.uniform(-0.1, 0.1, 2), home + rng.uniform(-0.1, 0.1, 2)
    size = np.array([0.04, 0.03, 0.025]) if geom == "box" else np.array([0.045, 0.025, 0.0])
    z = scene.TABLE_TOP + (size[2] if geom == "box" else size[1])
    s = np.linspace(0.0, 1.0, steps)[:, None]
    xy = start + s * (goal - start) + 0.01 * np.sin(7 * s) * rng.normal(size=2)
    yaw = rng.uniform(-np.pi, np.pi) + 1.5 * s[:, 0]
    masks = mask_geometry.object_mask(geom, np.broadcast_to(size, (steps, 3)), xy, yaw, np.full(steps, z))
    return masks, mask_geometry.object_mask(geom, size, goal, yaw[-1] + 0.3, z)


@pytest.mark.parametrize("kind", AGENT_KINDS)
def test_numpy_and_torch_match_jax_over_an_episode(kind, exported, jax_encode):
    policy, nets, path = exported[kind]
    act = jax.jit(lambda carry, obs: nets.act(policy.actor_params, carry, obs, jax.random.PRNGKey(0), True))
    np_policy = NumpyPolicy.from_file(path)
    np_int = NumpyPolicy.from_file(path)  # the same policy through act(): a_s decoded to substeps
    others = [np_policy]
    if HAVE_TORCH:
        from mjx_push.export.torch_policy import TorchPolicy

        others.append(TorchPolicy.from_file(path))
    geom = "box" if kind in ("vpm", "ugru") else "cylinder"
    masks, goal_mask = _moving_object(geom, AGENT_KINDS.index(kind))
    assert len({m.tobytes() for m in masks}) > 30 and masks.any(axis=(1, 2)).all()
    # The flange follows the JAX policy's actions (closed loop, as in an episode), with observation noise.
    # The JAX episode runs first and the others replay its observations: interleaving XLA's and BLAS's
    # thread pools step by step on 2 busy cores slows both by an order of magnitude.
    cfg, rng = policy.config.env, np.random.default_rng(1)
    ee = scene.home_flange_pos()[:2].copy()
    carry = nets.init_carry(1)
    z_goal = jax_encode(policy.encoder_params, goal_mask[None])
    ee_obs, a_jax = [], []
    for t in range(50):
        ee_obs.append(ee + cfg.obs_noise * rng.normal(size=2))
        step = {
            "ee_xy": jnp.asarray(ee_obs[t][None], jnp.float32),
            "z_obj": jax_encode(policy.encoder_params, masks[t][None]),
            "z_goal": z_goal,
        }
        a, carry = act(carry, step)
        a_jax.append(np.asarray(a[0]))
        ee = np.clip(
            ee + 0.05 * a_jax[t][:2], [cfg.workspace_x[0], cfg.workspace_y[0]], [cfg.workspace_x[1], cfg.workspace_y[1]]
        )
    worst = [0.0] * len(others)
    for t in range(50):
        raw = [p.act_raw(masks[t], goal_mask, ee_obs[t]) for p in others]
        for i, a in enumerate(raw):
            assert a.shape == (3,) and np.all(np.abs(a) <= 1.0)
            worst[i] = max(worst[i], float(np.max(np.abs(a - a_jax[t]))))
        a_x, a_y, n = np_int.act(masks[t], goal_mask, ee_obs[t])
        assert (a_x, a_y) == (float(raw[0][0]), float(raw[0][1]))
        assert isinstance(n, int) and n == int(jax_decode_substeps(jnp.float32(raw[0][2]), cfg.substeps))
    names = ["numpy", "torch"][: len(worst)]
    print(f"{kind}: max |action - JAX action| over 50 steps: {dict(zip(names, worst))}")
    assert max(worst) < ATOL, dict(zip(names, worst))


def test_encoder_matches_jax_on_a_batch(exported, encoder_params, jax_encode):
    rng = np.random.default_rng(0)
    masks = np.zeros((6, 64, 64), bool)
    for m in masks:
        r, c = rng.integers(0, 44, 2)
        h, w = rng.integers(5, 20, 2)
        m[r : r + h, c : c + w] = True
    p = NumpyPolicy.from_file(exported["vpm"][2])
    z = p.encode(masks)
    assert z.shape == (6, 6) and z.dtype == np.float32
    np.testing.assert_allclose(z, np.asarray(jax_encode(encoder_params, masks)), atol=ATOL)
    blas = NumpyPolicy.from_file(exported["vpm"][2], use_blas=True)
    np.testing.assert_allclose(blas.encode(masks), z, atol=ATOL)
    assert p.encode(masks[0]).shape == (6,)
    np.testing.assert_array_equal(p.encode(masks.reshape(2, 3, 64, 64)).reshape(6, 6), z)


def test_goal_latent_is_cached_and_recomputed_on_change(exported):
    p = NumpyPolicy.from_file(exported["ugru"][2])
    calls = []
    encode = p.encode
    p.encode = lambda m: calls.append(m.shape) or encode(m)
    obj = np.zeros((64, 64), bool)
    obj[20:30, 20:30] = True
    goal = np.roll(obj, 8, axis=1)
    for _ in range(3):
        p.act(obj, goal, np.array([0.4, 0.0]))
    assert len(calls) == 4  # one goal encoding, three object encodings
    p.act(obj, np.roll(goal, 3, axis=0), np.array([0.4, 0.0]))
    assert len(calls) == 6
    with pytest.raises(ValueError, match="object_mask must have shape"):
        p.act(obj[:32], goal, np.zeros(2))
    with pytest.raises(ValueError, match="ee_xy"):
        p.act(obj, goal, np.array([np.nan, 0.0]))


def test_reset_restarts_the_memory(exported):
    for kind in ("stacked", "ugru"):
        p = NumpyPolicy.from_file(exported[kind][2])
        obj = np.zeros((64, 64), bool)
        obj[10:25, 30:40] = True
        goal = np.roll(obj, 10, axis=0)
        first = [p.act_raw(np.roll(obj, t, axis=1), goal, np.array([0.4, 0.01 * t])) for t in range(4)]
        p.reset()
        again = [p.act_raw(np.roll(obj, t, axis=1), goal, np.array([0.4, 0.01 * t])) for t in range(4)]
        np.testing.assert_array_equal(np.stack(first), np.stack(again))
        assert not np.allclose(first[0], first[3])  # the memory does carry something


def test_substep_decoding_matches_the_environment():
    lo_hi = EnvConfig().substeps
    values = [-2.0, -1.0, -0.999, 0.0, 0.5, 0.999999, 1.0, 3.0] + [a_s_for(n) for n in (10, 11, 305, 599, 600)]
    values += list(np.linspace(-1, 1, 1001, dtype=np.float32))
    for a in values:
        assert decode_substeps(a, lo_hi) == int(jax_decode_substeps(jnp.float32(a), lo_hi)), a
    assert decode_substeps(-1.0, (1, 5)) == 1 and decode_substeps(1.0, (1, 5)) == 5


# --- the file format -------------------------------------------------------------------------------
def test_the_numpy_side_knows_the_same_agent_kinds():
    assert pfile.AGENT_KINDS == AGENT_KINDS  # export/policy_file.py cannot import mjx_push.train.config (JAX)


def test_metadata_record(exported):
    pf = pfile.load_npz(exported["egru"][2])
    m = pf.metadata
    assert m["format"] == pfile.FORMAT and m["format_version"] == 1
    assert m["package_version"] == importlib.metadata.version("mjx-push")
    assert m["agent"]["kind"] == "egru" and m["agent"]["gru_hidden"] == 32
    assert m["observation"]["flat_order"] == ["ee_xy", "z_obj", "z_goal"]
    assert m["observation"]["gru_input_order"] == ["z_obj", "z_goal", "ee_xy"]
    assert m["observation"]["stack"] == 5
    cfg = exported["egru"][0].config.env
    assert m["action"]["substeps"] == list(cfg.substeps) and m["action"]["action_scale"] == cfg.action_scale
    assert m["action"]["workspace_x"] == list(cfg.workspace_x)
    assert m["action"]["controller_gain"] == cfg.controller.gain
    assert m["agent"]["obs_norm"] == {"clip": 5.0} and "actor/norm/z_std" in pf.arrays
    assert pfile.load_npz(exported["ugru"][2]).metadata["agent"]["obs_norm"] is None  # reference: none
    assert abs(m["action"]["home_flange_z"] - 0.5905) < 1e-3
    assert m["camera"]["image_size"] == 64 and m["camera"]["fovy_deg"] == 65.0
    assert "columns grow with world +x" in m["camera"]["pixel_convention"]
    assert "curve" not in m["encoder"]["record"]
    assert m["scores"] == {"best_eval_mean_reward": -42.0, "best_eval_success_rate": None}  # NaN -> null
    assert m["run_config"]["agent"] == "egru"
    assert all(a.dtype == np.float32 for a in pf.arrays.values())
    assert "encoder/logvar/kernel" not in pf.arrays


def test_load_as_policy_round_trips(exported, jax_encode):
    policy, _, path = exported["ugru"]
    back = pfile.load_as_policy(path)
    assert back.config == policy.config
    assert jax.tree.structure(back.actor_params) == jax.tree.structure(policy.actor_params)
    jax.tree.map(np.testing.assert_array_equal, back.actor_params, policy.actor_params)
    for name, layer in policy.encoder_params.items():
        if name != "logvar":  # not exported: comes back as zeros
            jax.tree.map(np.testing.assert_array_equal, back.encoder_params[name], layer)
    masks = np.zeros((2, 64, 64), bool)
    masks[0, 10:30, 10:20] = masks[1, 30:50, 20:40] = True
    np.testing.assert_array_equal(jax_encode(back.encoder_params, masks), jax_encode(policy.encoder_params, masks))
    assert back.scores["best_eval_mean_reward"] == -42.0


def _rewrite(src: Path, dst: Path, mutate) -> Path:
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    mutate(arrays)
    with open(dst, "wb") as f:
        np.savez(f, **arrays)
    return dst


def _set_meta(arrays, **fields):
    meta = json.loads(arrays[pfile.METADATA_KEY].tobytes())
    meta.update(fields)
    arrays[pfile.METADATA_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)


def test_load_errors_name_the_file_and_the_problem(exported, tmp_path):
    src = exported["ugru"][2]
    data = src.read_bytes()
    cases = {
        "not found": tmp_path / "missing.npz",
        "not an .npz": tmp_path / "text.npz",
        "truncated": tmp_path / "truncated.npz",
        "lacks 1 array": _rewrite(src, tmp_path / "missing_array.npz", lambda a: a.pop("actor/mean_head/bias")),
        "has shape": _rewrite(
            src,
            tmp_path / "shape.npz",
            lambda a: a.update({"actor/features/cell/hn/kernel": np.zeros((32, 31), np.float32)}),
        ),
        "format version 2": _rewrite(src, tmp_path / "version.npz", lambda a: _set_meta(a, format_version=2)),
        "no '__metadata__'": _rewrite(src, tmp_path / "nometa.npz", lambda a: a.pop(pfile.METADATA_KEY)),
        "not an mjx-push NumPy policy": _rewrite(src, tmp_path / "fmt.npz", lambda a: _set_meta(a, format="other")),
        "dtype float64": _rewrite(
            src,
            tmp_path / "f64.npz",
            lambda a: a.update({"encoder/mean/bias": a["encoder/mean/bias"].astype(np.float64)}),
        ),
        "non-finite": _rewrite(
            src, tmp_path / "nan.npz", lambda a: a.update({"encoder/mean/bias": np.full(6, np.nan, np.float32)})
        ),
        "does not describe": _rewrite(
            src, tmp_path / "extra.npz", lambda a: a.update({"extra": np.zeros(1, np.float32)})
        ),
    }
    (tmp_path / "text.npz").write_text("not a zip at all")
    (tmp_path / "truncated.npz").write_bytes(data[: len(data) // 2])
    for problem, path in cases.items():
        with pytest.raises(ValueError, match=problem) as err:
            pfile.load_npz(path)
        assert str(path) in str(err.value)


def test_corrupt_member_is_reported(exported, tmp_path):
    src = exported["vpm"][2]
    with zipfile.ZipFile(src) as z:
        info = z.getinfo("encoder/Conv_3/kernel.npy")
    data = bytearray(src.read_bytes())
    data[info.header_offset + 200 : info.header_offset + 264] = b"\xff" * 64  # inside the array data
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="corrupt"):
        pfile.load_npz(bad)


def test_export_rejects_a_non_npz_name(exported, tmp_path):
    with pytest.raises(ValueError, match=r"\.npz"):
        pfile.export_policy(exported["vpm"][0], tmp_path / "policy.bin")


def _acts_without_jax(path: Path) -> None:
    """Load `path` with NumpyPolicy and act once in a fresh process that must import none of JAX, flax,
    torch or MuJoCo."""
    code = (
        "import sys, numpy as np\n"
        "from mjx_push.export.numpy_policy import NumpyPolicy\n"
        f"p = NumpyPolicy.from_file({str(path)!r})\n"
        "m = np.zeros((64, 64), bool); m[20:30, 20:30] = True\n"
        "print(p.act(m, np.roll(m, 5, axis=0), np.array([0.4, 0.0])))\n"
        "bad = [k for k in ('jax', 'jaxlib', 'flax', 'torch', 'mujoco') if k in sys.modules]\n"
        "assert not bad, bad\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_loading_and_acting_never_import_jax(exported):
    _acts_without_jax(exported["egru"][2])


# --- torch -----------------------------------------------------------------------------------------
def test_torch_missing_gives_an_install_hint(exported):
    # A fresh process where importing torch fails, as on a machine without it (installed or not here).
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # import torch now raises ImportError\n"
        "from mjx_push.export.torch_policy import TorchPolicy\n"
        "try:\n"
        f"    TorchPolicy.from_file({str(exported['vpm'][2])!r})\n"
        "except ImportError as e:\n"
        "    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and 'pip install -e ".[torch]"' in r.stdout, r.stdout + r.stderr


@pytest.mark.skipif(not HAVE_TORCH, reason=NO_TORCH)
def test_torch_module_batches_like_the_numpy_policy(exported):
    import torch

    from mjx_push.export.policy_file import load_npz
    from mjx_push.export.torch_policy import build_net

    pf = load_npz(exported["stacked"][2])
    net = build_net(pf)
    assert isinstance(net, torch.nn.Module)
    p = NumpyPolicy(pf)
    rng = np.random.default_rng(1)
    masks = rng.random((3, 64, 64)) < 0.2
    ee = rng.uniform(0.3, 0.5, (3, 2)).astype(np.float32)
    with torch.no_grad():
        z = net.encode(torch.from_numpy(masks.astype(np.float32)))
        a, carry = net.step(net.initial_carry(3), torch.from_numpy(ee), z, z.flip(0))
    np.testing.assert_allclose(z.numpy(), p.encode(masks), atol=ATOL)
    for i in range(3):
        p.reset()
        np.testing.assert_allclose(
            a[i].numpy(), p.step_latent(p.encode(masks[i]), p.encode(masks[2 - i]), ee[i]), atol=ATOL
        )


# --- the commands ----------------------------------------------------------------------------------
def test_export_command_from_a_run_directory(exported, tmp_path):
    policy, _, direct = exported["stacked"]
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    save_policy(run_dir / "best_policy", policy.config, policy.actor_params, policy.encoder_params, policy.scores)
    out = tmp_path / "cli.npz"
    meta = Export(run_dir, out).run()
    assert meta["agent"]["kind"] == "stacked"
    a, b = pfile.load_npz(out), pfile.load_npz(direct)
    assert a.arrays.keys() == b.arrays.keys()
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    assert Export(run_dir / "best_policy.json", tmp_path / "again.npz").run()["agent"]["kind"] == "stacked"
    meta = Export(run_dir, tmp_path / "traced.npz", provenance=("budget=cpu-long", "note=a=b")).run()
    assert meta["provenance"]["budget"] == "cpu-long" and meta["provenance"]["note"] == "a=b"
    assert meta["provenance"]["source"] == str(run_dir / "best_policy")
    with pytest.raises(ValueError, match="--provenance takes KEY=VALUE items, got 'budget'"):
        Export(run_dir, tmp_path / "y.npz", provenance=("budget",)).run()
    assert not (tmp_path / "y.npz").exists()  # refused before anything is written
    with pytest.raises(ValueError, match=f"SOURCE {tmp_path / 'nothing'}: no such file or directory"):
        Export(tmp_path / "nothing", tmp_path / "x.npz").run()
    with pytest.raises(ValueError, match="SOURCE: run directory"):
        Export(tmp_path, tmp_path / "x.npz").run()
    with pytest.raises(ValueError, match="OUT.npz must be an .npz"):
        Export(run_dir, tmp_path / "x.zip").run()


def test_deploy_command_writes_the_metrics_of_evals_episodes(exported, tmp_path, monkeypatch):
    # a_s pinned at -1 (the shortest steps) keeps the simulated episodes short.
    from mjx_push.train.episodes import EvalSpec, episode_objects

    policy = exported["egru"][0]
    actor = jax.tree.map(lambda v: v, policy.actor_params)
    actor["params"]["mean_head"]["bias"] = actor["params"]["mean_head"]["bias"].at[2].set(-100.0)
    quick = tmp_path / "quick.npz"
    pfile.export_policy(Policy(policy.config, actor, policy.encoder_params, policy.scores), quick)
    out = tmp_path / "deploy.json"
    result = Deploy(policy=quick, episodes=3, seed=3, mask_source="analytic", out=out).run()
    saved = json.loads(out.read_text())
    assert saved["summary"] == result["summary"]
    assert set(saved["summary"]) == {
        "success",
        "reward",
        "overshoot",
        "distance",
        "start_distance",
        "final_distance",
    }  # the table of mjx-push eval
    for m in saved["summary"].values():
        assert set(m) == {"mean", "sem", "n"} and m["n"] == 3
    assert -50.0 <= saved["summary"]["reward"]["mean"] <= 0.0
    assert saved["setting"] == "difficult" and saved["shape"] == "all"  # eval's defaults
    assert [e["geom_type"] for e in saved["episodes"]] == ["box", "cylinder", "box"]  # eval's "all"
    # Episode i is mjx-push eval's episode i: the same object, start and goal.
    spec = EvalSpec(episodes=3, seed=3)
    params, _ = episode_objects(spec, policy.config.env.objects, "cylinder", np.array([1]))
    start = np.asarray(params.start[0, :2]) - np.asarray(params.goal[0, :2])
    assert saved["episodes"][1]["start_distance"] == pytest.approx(float(np.linalg.norm(start)), abs=1e-6)
    # The simulated cell stressed as a real one (docs/robustness.md): --perturb's rows at its level reach
    # the CPU MuJoCo environment (what they do there: tests/test_perturb.py), and the record says so.
    from mjx_push import perturb
    from mjx_push.export import cpu_env

    seen = []

    class Spy(cpu_env.CpuPushEnv):
        def __init__(self, config, **kwargs):
            seen.append(config.perturb)
            super().__init__(config, **kwargs)

    monkeypatch.setattr(cpu_env, "CpuPushEnv", Spy)
    shaken = Deploy(
        policy=quick, episodes=1, seed=3, mask_source="analytic", perturb=("camera", "latency"), perturb_level="severe"
    ).run()
    assert seen == [perturb.suite_config(("camera", "latency"), "severe")] and seen[0] != perturb.PerturbConfig()
    assert shaken["perturb"] == {"rows": ["camera", "latency"], "level": "severe"} and saved["perturb"] is None
    assert saved["mask_source"] == "analytic"


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("episodes", 0, "--episodes"),
        ("mask_source", "camera", "--mask-source"),
        ("sim", "mjx", "--sim"),
        ("video", Path("out.avi"), "--video"),
        ("mass", (0.1, 0.2), "--mass needs --setting custom"),
        ("policy", Path("/nonexistent/policy.npz"), "POLICY.npz /nonexistent/policy.npz: no such file"),
    ],
)
def test_deploy_rejects_bad_arguments(exported, field, value, match):
    args = {"policy": exported["vpm"][2], "episodes": 1, "mask_source": "analytic", field: value}
    with pytest.raises(ValueError, match=match):
        Deploy(**args).run()


# --- metrics ---------------------------------------------------------------------------------------
def test_summarize_records_mean_and_standard_error():
    eps = [
        {"success": True, "reward": -10, "overshoot": 0, "distance": 3},
        {"success": False, "reward": -50, "overshoot": 2, "distance": 0},
        {"success": True, "reward": -20, "overshoot": 1, "distance": 0},
        {"success": True, "reward": -30, "overshoot": 1, "distance": 1},
    ]
    s = summarize_records(eps)
    assert s["success"] == {"mean": 0.75, "sem": 0.25, "n": 4}  # sd 0.5 (ddof 1) / sqrt(4)
    assert s["reward"]["mean"] == -27.5
    assert math.isclose(s["reward"]["sem"], math.sqrt(875 / 3 / 4), rel_tol=1e-12)
    assert s["overshoot"]["mean"] == 1.0 and math.isclose(s["overshoot"]["sem"], math.sqrt(2 / 3 / 4), rel_tol=1e-12)
    assert s["distance"]["mean"] == 1.0 and math.isclose(s["distance"]["sem"], math.sqrt(6 / 3 / 4), rel_tol=1e-12)
    one = summarize_records(eps[:1])
    assert one["reward"] == {"mean": -10.0, "sem": 0.0, "n": 1}
    with pytest.raises(ValueError, match="at least one"):
        summarize_records([])
    with pytest.raises(ValueError, match="episode 1 has no 'distance'"):
        summarize_records([eps[0], {"success": True, "reward": -1, "overshoot": 0}])


# --- files that reference the package's encoder; shipped policies ------------------------------------
@pytest.fixture(scope="module")
def package_exported(tmp_path_factory):
    """(embedded .npz, package-referencing .npz) of one eGRU trained with the package's own encoder."""
    policy, _ = _policy("egru", enc.load(None), seed=11)
    root = tmp_path_factory.mktemp("package")
    embedded, referenced = root / "embedded.npz", root / "egru.npz"
    pfile.export_policy(policy, embedded)
    meta = pfile.export_policy(policy, referenced, encoder="package", provenance={"source": "runs/x", "commit": "abc"})
    return policy, embedded, referenced, meta


def test_package_encoder_reference_loads_the_same_policy_at_a_fraction_of_the_size(package_exported):
    policy, embedded, referenced, meta = package_exported
    assert meta["encoder"]["weights"] == {"source": "package", "sha256": pfile.package_encoder_sha256()}
    assert meta["provenance"] == {"source": "runs/x", "commit": "abc"}
    assert referenced.stat().st_size < 0.2 * embedded.stat().st_size
    with np.load(referenced) as z:
        assert not any(name.startswith("encoder/") for name in z.files)
    a, b = pfile.load_npz(embedded), pfile.load_npz(referenced)
    assert a.arrays.keys() == b.arrays.keys()
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    m, g = _moving_object("box", 3, steps=3)
    p, q = NumpyPolicy.from_file(embedded), NumpyPolicy.from_file(referenced)
    np.testing.assert_array_equal(p.act(m[0], g, np.array([0.4, 0.0])), q.act(m[0], g, np.array([0.4, 0.0])))


def test_package_encoder_reference_is_refused_when_the_encoder_differs(
    package_exported, exported, tmp_path, monkeypatch
):
    policy, _, _ = exported["vpm"]  # a random encoder, not the package's
    with pytest.raises(ValueError, match="this policy's encoder is not the one the package ships"):
        pfile.export_policy(policy, tmp_path / "x.npz", encoder="package")
    with pytest.raises(ValueError, match="encoder must be one of"):
        pfile.export_policy(policy, tmp_path / "x.npz", encoder="none")
    # Another encoder under the package's name: the recorded sha256 no longer matches, and the file says so.
    other = tmp_path / "encoder.msgpack"
    other.write_bytes(pfile.package_encoder_path().read_bytes() + b"\0")
    monkeypatch.setattr(pfile, "package_encoder_path", lambda: other)
    with pytest.raises(ValueError, match="exported against the package encoder with sha256 .* but this mjx-push ships"):
        pfile.load_npz(package_exported[2])


def test_loading_a_package_referencing_file_never_imports_jax(package_exported):
    _acts_without_jax(package_exported[2])  # the package's encoder is read with NumPy and msgpack


def test_pretrained_names_resolve_for_eval_and_deploy(package_exported, tmp_path, monkeypatch):
    from mjx_push.cli.options import resolve_policy  # what `mjx-push eval POLICY` reads POLICY with
    from mjx_push.export import pretrained

    with pytest.raises(ValueError, match="unknown pretrained policy 'pretrained:egru': this mjx-push ships none"):
        pretrained.resolve("pretrained:egru", tmp_path)
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    (shipped / "egru.npz").write_bytes(package_exported[2].read_bytes())
    monkeypatch.setattr(pretrained, "DIRECTORY", shipped)
    assert pretrained.available() == {"egru": shipped / "egru.npz"}
    assert pretrained.resolve("runs/x") == Path("runs/x")  # not a reference: a path
    with pytest.raises(
        ValueError, match="unknown pretrained policy 'pretrained:vpm': this mjx-push ships pretrained:egru"
    ):
        pretrained.resolve("pretrained:vpm")
    policy = resolve_policy(Path("pretrained:egru"))
    assert policy.config.agent == "egru"
    np.testing.assert_array_equal(
        policy.actor_params["params"]["mean_head"]["kernel"],
        package_exported[0].actor_params["params"]["mean_head"]["kernel"],
    )
    d = Deploy(policy=Path("pretrained:egru"), episodes=1)
    d._check()
    assert d.policy == shipped / "egru.npz"


def test_the_shipped_policies_load_act_and_name_their_origin():
    """Every policy in export/pretrained_policies/ is a package-encoder file of its agent kind that
    loads with NumPy and acts, and is protocol v1's seed-0 run of its agent (or that run trained again
    from the same commit and seed), whose record is committed beside the comparison's data."""
    from mjx_push.export import pretrained

    ships = pretrained.available()
    assert set(ships) == set(AGENT_KINDS), ships
    masks, goal = _moving_object("box", 5, steps=3)
    data = Path(__file__).resolve().parents[1] / "docs" / "data" / "comparison-v1"
    for name, path in ships.items():
        f = pfile.load_npz(path)
        assert f.kind == name
        assert f.metadata["encoder"]["weights"] == {"source": "package", "sha256": pfile.package_encoder_sha256()}
        prov, run_config = f.metadata["provenance"], f.metadata["run_config"]
        assert prov["protocol"] == "v1" and prov["actor"] == "final_policy" and len(prov["trained_commit"]) >= 7
        assert "+dirty" not in prov["commit"]  # exported from a clean commit
        assert run_config["preset"] == "teacher-free" and run_config["train"]["loop"]["seed"] == 0
        assert prov["run"] in (f"{name}-s0", f"{name}-s0-machine2")
        record = data / ("reruns" if "rerun_of" in prov else "runs") / f"{prov['run']}.json"
        assert "rerun_of" not in prov or prov["rerun_of"] == f"{name}-s0"
        assert json.loads(record.read_text())["commit"].startswith(prov["trained_commit"])
        assert path.stat().st_size < 1_000_000
        policy = NumpyPolicy.from_file(path)
        for m in masks:
            a = policy.act_raw(m, goal, np.array([0.45, 0.0]))
            assert a.shape == (3,) and np.all(np.isfinite(a)) and np.all(np.abs(a) <= 1.0)
