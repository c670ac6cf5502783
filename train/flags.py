"""Error messages in the user's words: configuration errors name internal fields ("loop.num_envs",
"objects.mass"); the command line re-raises them naming the option the user typed ("--num-envs")."""

from __future__ import annotations

import contextlib
import re


@contextlib.contextmanager
def flag_errors(names: dict[str, str]):
    """Re-raise a ValueError raised inside the block with each field of `names` (field -> option) replaced
    by its option. Other exceptions, and messages that name none of the fields, pass unchanged."""
    try:
        yield
    except ValueError as e:
        msg = str(e)
        for field in sorted(names, key=len, reverse=True):
            # A field matches whole, optionally under the run config's "train." or "env." prefixes.
            msg = re.sub(rf"(?<![\w.-])(?:train\.|env\.)?{re.escape(field)}(?!\w)", names[field], msg)
        if msg == str(e):
            raise
        raise type(e)(msg) from None
