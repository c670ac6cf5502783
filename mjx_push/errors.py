"""The one exception type for bad input.

`ConfigError` is what the package raises when something a user supplied is wrong: a configuration
value, a command-line option, a file (run record, checkpoint, policy, video path), an action or an
image given to the NumPy policy or the deployment loop. Its message names what is wrong. It is a
`ValueError`, so code that catches `ValueError` keeps working; the command line turns it (and only it)
into a one-line message and exit status 2, and lets every other exception, a bug among them, raise
with its traceback.
"""


class ConfigError(ValueError):
    """Something the user supplied is wrong; the message names it and what would be right."""
