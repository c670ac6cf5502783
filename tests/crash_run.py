"""Run by tests/test_run.py in a fresh process: train the toy run with a checkpoint after every batch and
SIGKILL this process while its third checkpoint (120 env steps) is being written, at the worst moment:
every file of it written, not yet committed (orbax commits a checkpoint by renaming its temporary
directory).

    python -m tests.crash_run RUN_DIR ENCODER
"""

import os
import signal
import sys

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

from orbax.checkpoint._src.path import atomicity

from tests.helpers import TOY_TAU, toy_run_config, use_test_compilation
from mjx_push.train.runs import run as run_mod
from tests.toy import make_toy

use_test_compilation()  # the test process's: the toy trainer is compiled there already

KILL_AT_STEP = "120"  # the third checkpoint (env steps)
_finalize = atomicity.AtomicRenameTemporaryPath.finalize


async def _finalize_then_die(self, *args, **kwargs):
    if self.get_final().name == KILL_AT_STEP:  # the commit of the whole step directory
        os.kill(os.getpid(), signal.SIGKILL)
    return await _finalize(self, *args, **kwargs)


def main() -> None:
    run_dir, encoder = sys.argv[1], sys.argv[2]
    atomicity.AtomicRenameTemporaryPath.finalize = _finalize_then_die
    run_mod.run(toy_run_config(encoder), run_dir, adapter=make_toy(success_tau=TOY_TAU), checkpoint_every=1)
    sys.exit("the run finished: the kill never happened")


if __name__ == "__main__":
    main()
