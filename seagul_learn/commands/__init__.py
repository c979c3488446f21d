"""``seagul`` subcommands: each public module defines ``COMMAND`` (see :mod:`seagul_learn.cli`)."""
