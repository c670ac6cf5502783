"""One process of a data-parallel run on localhost, started by tests/test_data_parallel.py: joins the
run through `jax.distributed` with one CPU device of its own, trains through `mjx_push.train.runs.run.run` in a shared run directory, and writes its final learner state (all
but the replay shards) to `RUN_DIR/state-<process id>.npz` and its summary to `RUN_DIR/summary-<process id>.json`.

    python -m tests.distributed_worker PORT PROCESS_ID NUM_PROCESSES RUN_DIR CONFIG_JSON [--stop-after N] [--resume]

CONFIG_JSON is a run configuration (`mjx_push.train.runs.run.config_dict`); `--toy` trains it on the toy task
(tests/toy.py), otherwise on the MJX pushing scene.
"""

import argparse
import json
import sys
from pathlib import Path

import mjx_push

mjx_push.xla.use_cpu_devices(1)  # one CPU device per process: the run's devices are its processes'

import jax  # noqa: E402
import numpy as np  # noqa: E402

from mjx_push.train import data_parallel  # noqa: E402
from mjx_push.train.runs import run as run_mod  # noqa: E402
from mjx_push.train import presets  # noqa: E402
from tests.helpers import use_test_compilation  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("port", type=int)
    p.add_argument("process_id", type=int)
    p.add_argument("num_processes", type=int)
    p.add_argument("run_dir", type=Path)
    p.add_argument("config", type=Path)
    p.add_argument("--toy", action="store_true")
    p.add_argument("--stop-after", type=int, default=None)
    p.add_argument("--resume", action="store_true")
    a = p.parse_args(argv)
    use_test_compilation(disable_optimizations=a.toy)  # as the test process, so compiled code is shared
    data_parallel.initialize(f"localhost:{a.port}", a.num_processes, a.process_id)
    cfg = presets.config_from_dict(json.loads(a.config.read_text()))
    adapter = None
    if a.toy:
        from tests.toy import make_toy

        adapter = make_toy(success_tau=cfg.env.success_tau, episode_len=cfg.env.episode_length)
    summary, state = run_mod.run(cfg, a.run_dir, resume=a.resume, adapter=adapter, stop_after=a.stop_after)
    # Every field but the replay shards (each process holds its own): this process's copy of each.
    local = jax.tree_util.tree_leaves_with_path(state.replace(buffer=None))
    np.savez(
        a.run_dir / f"state-{a.process_id}.npz",
        **{jax.tree_util.keystr(path): np.asarray(x.addressable_shards[0].data) for path, x in local},
    )
    summary = {**summary, "devices": jax.device_count(), "processes": jax.process_count()}
    (a.run_dir / f"summary-{a.process_id}.json").write_text(json.dumps(summary, default=float))
    jax.distributed.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
