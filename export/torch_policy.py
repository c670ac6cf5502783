"""The exported policy as a PyTorch `nn.Module` (optional: `pip install -e ".[torch]"`), built from the same
`.npz` as `mjx_push.export.numpy_policy` and giving the same actions.

    policy = TorchPolicy.from_file("egru.npz")       # reset() / act() / act_raw() / encode(), like NumpyPolicy
    net = policy.net                                 # the nn.Module: encode(masks), step(carry, ee, z_obj, z_goal)

The flax GRUCell is torch's `nn.GRUCell` with the hidden-side r and z biases fixed at zero (both gate
orders are r, z, n and both put the n gate's hidden bias inside r * (...)), so the recurrent agents load
into the stock cell. torch is imported only when a module is built.

Latency: a policy step is one small sample, which torch's intra-op threads only slow down; call
`torch.set_num_threads(1)` in a control process (measured 2 ms instead of 120 ms per step on a busy
2-core machine), as for NumPy's BLAS (see `mjx_push.export.numpy_policy`).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from mjx_push.export.numpy_policy import decode_substeps
from mjx_push.export.policy_file import PolicyFile, feature_dim, load_npz
from mjx_push.errors import ConfigError

INSTALL_HINT = 'PyTorch is not installed; install the optional extra with `pip install -e ".[torch]"` (torch==2.13.0)'


def _torch():
    try:
        import torch
    except ImportError as e:
        raise ImportError(INSTALL_HINT) from e
    return torch


@functools.cache
def _net_class():
    """The nn.Module class, defined on first use so that importing this module never imports torch."""
    torch = _torch()
    nn = torch.nn

    class PolicyNet(nn.Module):
        def __init__(self, pf: PolicyFile):
            super().__init__()
            meta, w = pf.metadata, pf.arrays
            t = lambda name: torch.from_numpy(np.array(w[name]))  # noqa: E731  (a copy: npz arrays are read-only)
            self.kind = meta["agent"]["kind"]
            self.stack = meta["agent"]["stack"]
            self.obs_dim = meta["observation"]["obs_dim"]
            self.image_size = meta["camera"]["image_size"]
            enc = meta["encoder"]
            convs = []
            for i in range(len(enc["channels"])):
                kernel = t(f"encoder/Conv_{i}/kernel")  # HWIO -> OIHW
                conv = nn.Conv2d(kernel.shape[2], kernel.shape[3], enc["kernel"], stride=enc["stride"])
                conv.weight.data.copy_(kernel.permute(3, 2, 0, 1))
                conv.bias.data.copy_(t(f"encoder/Conv_{i}/bias"))
                convs += [conv, nn.ReLU()]
            self.convs = nn.Sequential(*convs)
            self.enc_dense = self._linear(t, "encoder/Dense_0")
            self.enc_mean = self._linear(t, "encoder/mean")
            if self.kind in ("ugru", "egru"):
                cell = "actor/features/cell"
                ir, iz, in_ = (t(f"{cell}/{g}/kernel") for g in ("ir", "iz", "in"))
                self.gru = nn.GRUCell(ir.shape[0], ir.shape[1])
                self.gru.weight_ih.data.copy_(torch.cat([ir, iz, in_], dim=1).T)
                self.gru.weight_hh.data.copy_(torch.cat([t(f"{cell}/{g}/kernel") for g in ("hr", "hz", "hn")], dim=1).T)
                self.gru.bias_ih.data.copy_(torch.cat([t(f"{cell}/{g}/bias") for g in ("ir", "iz", "in")]))
                hn_bias = t(f"{cell}/hn/bias")
                self.gru.bias_hh.data.copy_(torch.cat([torch.zeros_like(hn_bias), torch.zeros_like(hn_bias), hn_bias]))
            n_mlp = len(meta["agent"]["hidden"])
            self.mlp = nn.ModuleList(self._linear(t, f"actor/mlp/Dense_{i}") for i in range(n_mlp))
            self.mean_head = self._linear(t, "actor/mean_head")
            self.log_std_head = self._linear(t, "actor/log_std_head")
            self.feature_dim = feature_dim(meta)
            norm = meta["agent"].get("obs_norm")
            self.norm_clip = None if not norm else float(norm["clip"])
            for g in ("ee_xy", "z"):  # identity statistics when the policy was trained without them
                mean = t(f"actor/norm/{g}_mean") if norm else torch.zeros(2 if g == "ee_xy" else self.obs_dim // 2 - 1)
                std = t(f"actor/norm/{g}_std") if norm else torch.ones_like(mean)
                self.register_buffer(f"{g}_mean", mean)
                self.register_buffer(f"{g}_std", std)

        @staticmethod
        def _linear(t, prefix: str) -> nn.Linear:
            kernel = t(f"{prefix}/kernel")
            lin = nn.Linear(*kernel.shape)
            lin.weight.data.copy_(kernel.T)
            lin.bias.data.copy_(t(f"{prefix}/bias"))
            return lin

        def encode(self, masks: torch.Tensor) -> torch.Tensor:
            """Latent means [B, 6] of masks [B, 64, 64]."""
            h = self.convs(masks.to(torch.float32)[:, None])  # NCHW
            h = h.permute(0, 2, 3, 1).reshape(h.shape[0], -1)  # flatten as NHWC, like the JAX encoder
            return self.enc_mean(torch.relu(self.enc_dense(h)))

        def initial_carry(self, batch: int) -> torch.Tensor:
            if self.kind in ("ugru", "egru"):
                return torch.zeros(batch, self.gru.hidden_size)
            if self.kind == "stacked":
                return torch.zeros(batch, self.stack, self.obs_dim)
            return torch.zeros(batch, 0)

        def step(self, carry, ee_xy, z_obj, z_goal):
            """One step for a batch: (deterministic action tanh(mean) [B, 3], new carry)."""
            if self.norm_clip is not None:
                c = self.norm_clip
                ee_xy = torch.clamp((ee_xy - self.ee_xy_mean) / self.ee_xy_std, -c, c)
                z_obj = torch.clamp((z_obj - self.z_mean) / self.z_std, -c, c)
                z_goal = torch.clamp((z_goal - self.z_mean) / self.z_std, -c, c)
            if self.kind in ("ugru", "egru"):
                carry = self.gru(torch.cat([z_obj, z_goal, ee_xy], dim=-1), carry)
                h = carry
            else:
                flat = torch.cat([ee_xy, z_obj, z_goal], dim=-1)
                if self.kind == "stacked":
                    carry = torch.cat([carry[:, 1:], flat[:, None]], dim=1)
                    h = carry.reshape(carry.shape[0], -1)
                else:
                    h = flat
            for lin in self.mlp:
                h = torch.relu(lin(h))
            return torch.tanh(self.mean_head(h)), carry

        def forward(self, carry, ee_xy, object_masks, z_goal):
            return self.step(carry, ee_xy, self.encode(object_masks), z_goal)

    return PolicyNet


def build_net(pf: PolicyFile):
    """The `nn.Module` (eval mode) for a loaded policy file."""
    return _net_class()(pf).eval()


class TorchPolicy:
    """`mjx_push.export.deploy.Policy` on the torch module: the same semantics as `NumpyPolicy`."""

    def __init__(self, pf: PolicyFile):
        self.torch = _torch()
        self.file = pf
        self.net = build_net(pf)
        self.substeps: tuple[int, int] = tuple(pf.metadata["action"]["substeps"])
        self.reset()

    @classmethod
    def from_file(cls, path: Path | str) -> TorchPolicy:
        return cls(load_npz(path))

    def reset(self) -> None:
        self._carry = self.net.initial_carry(1)
        self._goal_mask: np.ndarray | None = None
        self._z_goal = None

    def _check_mask(self, name: str, mask) -> np.ndarray:
        mask = np.asarray(mask)
        n = self.net.image_size
        if mask.shape != (n, n):
            raise ConfigError(f"{name} must have shape ({n}, {n}), got {mask.shape}")
        return mask.astype(bool)

    def encode(self, mask: np.ndarray) -> np.ndarray:
        """Latent means [..., 6] of masks [..., 64, 64]."""
        mask = np.asarray(mask)
        lead = mask.shape[:-2]
        with self.torch.no_grad():
            z = self.net.encode(self.torch.from_numpy(mask.reshape((-1,) + mask.shape[-2:]).astype(np.float32)))
        return z.numpy().reshape(lead + (z.shape[-1],))

    def act_raw(self, object_mask: np.ndarray, goal_mask: np.ndarray, ee_xy: np.ndarray) -> np.ndarray:
        torch = self.torch
        object_mask = self._check_mask("object_mask", object_mask)
        goal_mask = self._check_mask("goal_mask", goal_mask)
        ee = np.asarray(ee_xy, np.float32).reshape(-1)
        if ee.shape != (2,) or not np.all(np.isfinite(ee)):
            raise ConfigError(f"ee_xy must be two finite numbers (metres), got {ee_xy!r}")
        if self._z_goal is None or not np.array_equal(goal_mask, self._goal_mask):
            self._goal_mask = goal_mask.copy()
            self._z_goal = torch.from_numpy(self.encode(goal_mask)[None])
        with torch.no_grad():
            z_obj = self.net.encode(torch.from_numpy(object_mask[None].astype(np.float32)))
            a, self._carry = self.net.step(self._carry, torch.from_numpy(ee[None]), z_obj, self._z_goal)
        return a[0].numpy()

    def act(self, object_mask: np.ndarray, goal_mask: np.ndarray, ee_xy: np.ndarray) -> tuple[float, float, int]:
        a = self.act_raw(object_mask, goal_mask, ee_xy)
        return float(a[0]), float(a[1]), decode_substeps(a[2], self.substeps)
