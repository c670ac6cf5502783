"""Whether a burst of small eager programs over the CPU host devices deadlocks (jaxlib 0.10.2 does).

Each eager operation on arrays spread over several host devices is a program of its own over all of
them, often with a collective (concatenating two such arrays moves rows between the devices). Dispatched
back to back without waiting, as `jax.tree.map` over a state's leaves does, after a program with a loop
over the same devices (a batch's step has one; without it the same burst finished here), one device
waits in a collective the other never joins until XLA's rendezvous timeout aborts the process (40 s by
default). `mjx_push.batch` therefore waits for each eager join of its groups, and the suite reads a
data-parallel state on the host. This benchmark is the check to rerun on a new jaxlib: each case runs in
a process of its own with a short rendezvous timeout, and the table says which aborted.

    python -m benchmarks.collective_burst [--programs 40] [--repeats 20] [--out FILE]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.output import write_json

_CASE = """
import sys
import mjx_push
mjx_push.xla.use_cpu_devices()
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
programs, repeats, wait = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "wait"
mesh = Mesh(np.array(jax.devices()[:2]), ("d",))
x = jax.device_put(jnp.ones((256, 128)) * 0.01, NamedSharding(mesh, P("d")))
# A program over both devices with many outputs, as a batch's step is; its outputs are joined.
def work(y):
    return jax.lax.fori_loop(0, 300, lambda k, z: jnp.tanh(z @ z.T @ z * 0.01), y)
step = jax.jit(jax.shard_map(lambda y: [work(y) + i for i in range(programs)], mesh=mesh,
                             in_specs=P("d"), out_specs=P("d"), check_vma=False))
for _ in range(repeats):
    leaves = jax.block_until_ready(step(x))
    joined = []
    for leaf in leaves:
        joined.append(jnp.concatenate([leaf, leaf]))
        if wait:
            joined[-1].block_until_ready()
    jax.block_until_ready(joined)
"""


def run_case(programs: int, repeats: int, wait: bool, timeout_s: int) -> dict:
    """One case in a fresh process: did it finish, abort (the rendezvous timeout) or hang?"""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_cpu_collective_call_terminate_timeout_seconds={timeout_s}"
    args = [sys.executable, "-c", _CASE, str(programs), str(repeats), "wait" if wait else "burst"]
    t0 = time.monotonic()
    try:
        p = subprocess.run(args, env=env, capture_output=True, text=True, timeout=timeout_s * 4 + 60)
        outcome = "finished" if p.returncode == 0 else ("aborted" if "Termination timeout" in p.stderr else "failed")
    except subprocess.TimeoutExpired:
        outcome = "hung"
    return {"programs": programs, "repeats": repeats, "wait": wait, "outcome": outcome, "wall_s": time.monotonic() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--programs", type=int, default=40, help="eager joins dispatched per burst")
    ap.add_argument("--repeats", type=int, default=20, help="bursts per case")
    ap.add_argument("--timeout", type=int, default=5, help="XLA's rendezvous timeout in the cases, seconds")
    ap.add_argument("--out", type=Path, default=Path("outputs/collective_burst.json"))
    a = ap.parse_args(argv)
    for name, value in (("--programs", a.programs), ("--repeats", a.repeats), ("--timeout", a.timeout)):
        if value < 1:
            ap.error(f"{name} must be at least 1, got {value}")
    import jax

    import mjx_push

    mjx_push.xla.use_cpu_devices()
    if len(jax.devices()) < 2:  # one device: no collectives, every case would finish and mean nothing
        print(f"needs 2 host devices, this process has {len(jax.devices())} (MJX_PUSH_CPU_DEVICES, cores)")
        return 2
    rows = [
        run_case(n, a.repeats, wait, a.timeout) for n, wait in ((1, False), (a.programs, False), (a.programs, True))
    ]
    print("| joins per burst | each waits | outcome | wall (s) |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['programs']} | {'yes' if r['wait'] else 'no'} | {r['outcome']} | {r['wall_s']:.1f} |")
    write_json(
        a.out, {"benchmark": "collective_burst", "devices": len(jax.devices()), "timeout_s": a.timeout, "rows": rows}
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
