"""The exported policy in plain NumPy (no JAX, no flax): mask encoder, feature extractor, MLP, action.

    policy = NumpyPolicy.from_file("egru.npz")
    policy.reset()                                         # at the start of every episode
    a_x, a_y, substeps = policy.act(object_mask, goal_mask, ee_xy)

It follows `mjx_push.export.deploy.Policy`, so `mjx_push.export.deploy.run_episode` drives it on a robot or on `CpuPushEnv`.
Per step, as the trained JAX actor's online step (`mjx_push.train.networks.Networks.act`, deterministic):
z_obj = encoder mean of the object mask; z_goal = encoder mean of the goal mask, computed once per episode
(recomputed if the goal mask changes; a recurrent agent's memory is not rewound then, so start a new
episode for a new goal); the extractor's memory is carried step to step (VPM: none; Stacked: the last
`stack` observations, zeros before the first; GRU: the hidden state, zero at reset); action = tanh(mean).
A policy trained with input normalisation standardises ee_xy and both latents first (clipped).
Everything runs in float32 like the trained networks.

Latency: the encoder's convolutions dominate. By default they run in einsum's single-threaded loops
(~5 ms per step on one core, whatever the machine's load). `use_blas=True` sends them through BLAS: ~1 ms
with `OPENBLAS_NUM_THREADS=1` set before NumPy is imported, but with BLAS's default threads on a busy
machine 10-100 ms (the products are too small to gain from threads; measured on 2 loaded cores).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from mjx_push.export.policy_file import PolicyFile, load_npz
from mjx_push.errors import ConfigError
from mjx_push.task_rules import substep_count as decode_substeps  # a_s -> substeps, as mjx_push.env's (float32)

F32 = np.float32


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return F32(0.5) * (F32(1.0) + np.tanh(F32(0.5) * x))  # no overflow for large |x|


def _conv_valid(x: np.ndarray, weight: np.ndarray, bias: np.ndarray, k: int, stride: int, use_blas: bool) -> np.ndarray:
    """VALID convolution of NHWC input [B, H, W, C] -> [B, Ho, Wo, O] as one matrix product (im2col).
    `weight` is the HWIO kernel rearranged to [(C, k, k), O], the order of the window view's axes."""
    win = sliding_window_view(x, (k, k), axis=(1, 2))[:, ::stride, ::stride]  # [B, Ho, Wo, C, k, k]
    b, ho, wo = win.shape[:3]
    cols = win.reshape(b * ho * wo, -1)
    # einsum's own loops run on one thread: steady ~5 ms per encoding. BLAS is ~10x faster on an idle
    # machine but its threads make it 10-100 ms on a busy one (measured on 2 loaded cores).
    out = cols @ weight if use_blas else np.einsum("mk,kn->mn", cols, weight)
    return out.reshape(b, ho, wo, -1) + bias


class NumpyPolicy:
    """A trained actor and its mask encoder, from an exported `.npz` (see `mjx_push.export.policy_file`)."""

    def __init__(self, policy_file: PolicyFile, use_blas: bool = False):
        self.file = policy_file
        self.use_blas = use_blas
        meta = policy_file.metadata
        self.metadata = meta
        self.kind: str = meta["agent"]["kind"]
        self.substeps: tuple[int, int] = tuple(meta["action"]["substeps"])
        self.image_size: int = meta["camera"]["image_size"]
        self.stack: int = meta["agent"]["stack"]
        self.obs_dim: int = meta["observation"]["obs_dim"]
        w = policy_file.arrays
        enc = meta["encoder"]
        self._kernel, self._stride = enc["kernel"], enc["stride"]
        self._convs = []
        for i in range(len(enc["channels"])):
            kernel = w[f"encoder/Conv_{i}/kernel"]  # HWIO -> [(C, k, k), O], once
            weight = np.ascontiguousarray(kernel.transpose(2, 0, 1, 3).reshape(-1, kernel.shape[-1]))
            self._convs.append((weight, w[f"encoder/Conv_{i}/bias"]))
        self._enc_dense = (w["encoder/Dense_0/kernel"], w["encoder/Dense_0/bias"])
        self._enc_mean = (w["encoder/mean/kernel"], w["encoder/mean/bias"])
        self._mlp = [
            (w[f"actor/mlp/Dense_{i}/kernel"], w[f"actor/mlp/Dense_{i}/bias"])
            for i in range(len(meta["agent"]["hidden"]))
        ]
        self._mean_head = (w["actor/mean_head/kernel"], w["actor/mean_head/bias"])
        self._log_std_head = (w["actor/log_std_head/kernel"], w["actor/log_std_head/bias"])
        self._gru = {name: w[name].copy() for name in w if name.startswith("actor/features/cell/")}
        norm = meta["agent"].get("obs_norm")
        self._norm = (
            None
            if not norm
            else (F32(norm["clip"]), {g: (w[f"actor/norm/{g}_mean"], w[f"actor/norm/{g}_std"]) for g in ("ee_xy", "z")})
        )
        self.reset()

    @classmethod
    def from_file(cls, path: Path | str, use_blas: bool = False) -> NumpyPolicy:
        """`use_blas`: encoder convolutions through BLAS (fastest with OPENBLAS_NUM_THREADS=1, see above)."""
        return cls(load_npz(path), use_blas)

    @classmethod
    def from_policy(cls, policy, provenance: dict | None = None) -> NumpyPolicy:
        """The NumPy port of a `mjx_push.train.runs.policies.Policy`, through the file `mjx-push export` writes (so it
        is exactly what a user would deploy)."""
        import tempfile

        from mjx_push.export.policy_file import export_policy

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "policy.npz"
            export_policy(policy, path, provenance=provenance)
            return cls.from_file(path)

    @property
    def recurrent(self) -> bool:
        return self.kind in ("ugru", "egru")

    # --- the encoder ---------------------------------------------------------------------------------
    def encode(self, mask: np.ndarray) -> np.ndarray:
        """Latent means [..., 6] of masks [..., 64, 64] (bool or 0/1)."""
        mask = np.asarray(mask)
        n = self.image_size
        if mask.shape[-2:] != (n, n):
            raise ConfigError(f"mask must have shape (..., {n}, {n}), got {mask.shape}")
        lead = mask.shape[:-2]
        h = mask.reshape((-1, n, n, 1)).astype(F32)
        for weight, bias in self._convs:
            h = np.maximum(_conv_valid(h, weight, bias, self._kernel, self._stride, self.use_blas), F32(0))
        h = h.reshape(h.shape[0], -1)  # row-major over (h, w, c), as the JAX encoder flattens NHWC
        h = np.maximum(h @ self._enc_dense[0] + self._enc_dense[1], F32(0))
        z = h @ self._enc_mean[0] + self._enc_mean[1]
        return z.reshape(lead + (z.shape[-1],))

    # --- the actor, one step -------------------------------------------------------------------------
    def reset(self) -> None:
        """Start of an episode: clear the extractor's memory and the cached goal latent."""
        if self.recurrent:
            self._carry = np.zeros(self._gru["actor/features/cell/hr/kernel"].shape[0], F32)
        elif self.kind == "stacked":
            self._carry = np.zeros((self.stack, self.obs_dim), F32)
        else:
            self._carry = np.zeros(0, F32)
        self._goal_mask: np.ndarray | None = None
        self._z_goal: np.ndarray | None = None

    def _features(self, ee_xy: np.ndarray, z_obj: np.ndarray, z_goal: np.ndarray) -> np.ndarray:
        if self.recurrent:
            g = self._gru
            x = np.concatenate([z_obj, z_goal, ee_xy])  # the GRU's input order

            def lin(name: str, v: np.ndarray) -> np.ndarray:
                out = v @ g[f"actor/features/cell/{name}/kernel"]
                bias = g.get(f"actor/features/cell/{name}/bias")
                return out if bias is None else out + bias

            h = self._carry
            r = _sigmoid(lin("ir", x) + lin("hr", h))
            z = _sigmoid(lin("iz", x) + lin("hz", h))
            n = np.tanh(lin("in", x) + r * lin("hn", h))
            self._carry = (F32(1.0) - z) * n + z * h
            return self._carry
        flat = np.concatenate([ee_xy, z_obj, z_goal])
        if self.kind == "stacked":
            self._carry = np.concatenate([self._carry[1:], flat[None]])  # drop the oldest, append the newest
            return self._carry.reshape(-1)
        return flat

    def step_latent(self, z_obj: np.ndarray, z_goal: np.ndarray, ee_xy: np.ndarray) -> np.ndarray:
        """One step from latents (for users with their own encoder pass): raw action (3,) in [-1, 1]."""
        ee_xy = np.asarray(ee_xy, F32).reshape(-1)
        z_obj, z_goal = np.asarray(z_obj, F32).reshape(-1), np.asarray(z_goal, F32).reshape(-1)
        if ee_xy.shape != (2,) or not np.all(np.isfinite(ee_xy)):
            raise ConfigError(f"ee_xy must be two finite numbers (metres), got {ee_xy!r}")
        latent = self.obs_dim // 2 - 1
        if z_obj.shape != (latent,) or z_goal.shape != (latent,):
            raise ConfigError(f"z_obj and z_goal must have shape ({latent},), got {z_obj.shape} and {z_goal.shape}")
        if self._norm is not None:
            clip, stats = self._norm
            norm = lambda g, x: np.clip((x - stats[g][0]) / stats[g][1], -clip, clip)  # noqa: E731
            ee_xy, z_obj, z_goal = norm("ee_xy", ee_xy), norm("z", z_obj), norm("z", z_goal)
        h = self._features(ee_xy, z_obj, z_goal)
        for kernel, bias in self._mlp:
            h = np.maximum(h @ kernel + bias, F32(0))
        return np.tanh(h @ self._mean_head[0] + self._mean_head[1])

    def _goal_latent(self, goal_mask: np.ndarray) -> np.ndarray:
        if self._z_goal is None or not np.array_equal(goal_mask, self._goal_mask):
            self._goal_mask = goal_mask.copy()
            self._z_goal = self.encode(goal_mask)
        return self._z_goal

    def _check_mask(self, name: str, mask) -> np.ndarray:
        mask = np.asarray(mask)
        n = self.image_size
        if mask.shape != (n, n):
            raise ConfigError(f"{name} must have shape ({n}, {n}), got {mask.shape}")
        return mask.astype(bool)

    def act_raw(self, object_mask: np.ndarray, goal_mask: np.ndarray, ee_xy: np.ndarray) -> np.ndarray:
        """Raw deterministic action (a_x, a_y, a_s) (3,) float32 in [-1, 1]; advances the memory one step."""
        object_mask = self._check_mask("object_mask", object_mask)
        z_goal = self._goal_latent(self._check_mask("goal_mask", goal_mask))
        return self.step_latent(self.encode(object_mask), z_goal, ee_xy)

    def act(self, object_mask: np.ndarray, goal_mask: np.ndarray, ee_xy: np.ndarray) -> tuple[float, float, int]:
        """(a_x, a_y, a_s_substeps): a_x, a_y in [-1, 1] (times action_scale metres), a_s decoded to substeps."""
        a = self.act_raw(object_mask, goal_mask, ee_xy)
        return float(a[0]), float(a[1]), decode_substeps(a[2], self.substeps)
