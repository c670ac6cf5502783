"""Splitting a batch of environments over the devices of one backend.

MJX vectorises environments with `vmap`; one device runs the whole batch on one core of a CPU (see
`mjx_push.xla` for the host devices). `env_mesh(counts)` picks how many devices to split every shape
group over (the most devices, up to `jax.device_count()`, that divide every group's size: the split is
even) and `shard(fn, mesh)` runs a per-environment batched function on each device's slice with
`shard_map`. Nothing is exchanged between devices inside a substep: each device steps its own
environments and the results are the same as on one device.

jaxlib 0.11.2's CPU compiler crashes (segmentation fault) on the `shard_map` of MJX's reset over two
host devices; there `shard` constrains the inputs and outputs to the split instead and lets XLA's
partitioner split the batched computation (same results; checked by tests/test_batch.py).
"""

from __future__ import annotations

import jax
from jax.sharding import NamedSharding, PartitionSpec

from mjx_push.xla import jaxlib_line

AXIS = "envs"


def shard_map_compiles() -> bool:
    """False on the jaxlib line whose CPU compiler crashes on the environments' shard_map (0.11)."""
    line = jaxlib_line()
    return line is None or line < (0, 11) or jax.default_backend() != "cpu"


def env_mesh(counts: tuple[int, ...], max_devices: int | None = None) -> jax.sharding.Mesh | None:
    """A 1-D mesh over the default backend's devices that splits every count in `counts` evenly, or None
    when only one device would be used."""
    devices = jax.devices()
    n = min(len(devices), max_devices or len(devices))
    while n > 1 and any(c % n for c in counts):
        n -= 1
    if n <= 1:
        return None
    return jax.sharding.Mesh(devices[:n], (AXIS,), axis_types=(jax.sharding.AxisType.Auto,))


def shard(fn, mesh: jax.sharding.Mesh | None):
    """`fn` (pytrees with a leading environment axis in and out) run per device on its slice of the
    environments; `fn` itself when `mesh` is None."""
    if mesh is None:
        return fn
    spec = PartitionSpec(AXIS)
    sharding = NamedSharding(mesh, spec)
    constrain = lambda tree: jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), tree)  # noqa: E731
    if not shard_map_compiles():
        return lambda *args: constrain(fn(*constrain(args)))
    inner = jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False)

    def run(*args):
        return inner(*constrain(args))

    return run
