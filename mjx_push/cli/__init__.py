"""The `mjx-push` command line: one module per command, each a typed dataclass that tyro turns into a
subcommand and whose `run()` checks the options, builds the configuration and calls one function of the
library. It is the package's top layer (scene -> mjx_push.train -> mjx_push.export -> mjx_push.cli), so
a command may use the learner and the exported side alike."""

from __future__ import annotations

import sys

from mjx_push.cli.demo import Demo
from mjx_push.cli.deploy import Deploy
from mjx_push.cli.eval import Eval
from mjx_push.cli.export import Export
from mjx_push.cli.protocol import Protocol
from mjx_push.cli.reproduce import Reproduce
from mjx_push.cli.stress import Stress
from mjx_push.cli.train import Train
from mjx_push.cli.train_encoder import TrainEncoder
from mjx_push.errors import ConfigError

COMMANDS = {
    "train": Train,
    "eval": Eval,
    "stress": Stress,
    "reproduce": Reproduce,
    "protocol": Protocol,
    "train-encoder": TrainEncoder,
    "demo": Demo,
    "export": Export,
    "deploy": Deploy,
}


def main(argv: list[str] | None = None) -> int:
    """The `mjx-push` entry point."""
    import tyro

    from mjx_push import xla
    from mjx_push.train import compile_cache

    xla.use_cpu_devices()  # one CPU device per core, before anything starts JAX; spawned jobs inherit it
    compile_cache.enable()
    try:
        # Boolean options are single flags (--resume, --no-progress), not --x / --no-x pairs.
        cmd = tyro.extras.subcommand_cli_from_dict(
            COMMANDS, args=argv, prog="mjx-push", config=(tyro.conf.FlagCreatePairsOff,)
        )
        cmd.run()
    except ConfigError as e:  # the user's input is wrong and the message says how: no traceback
        print(f"mjx-push: error: {e}", file=sys.stderr)
        return 2
    return 0
