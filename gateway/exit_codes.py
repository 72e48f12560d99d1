"""The exit codes of every `invt-gateway` command, in one place.

A service manager acts on these numbers: the systemd unit (`config/invt-gateway.service`)
restarts the gateway on any non-zero code except `EXIT_CONFIG` (`RestartPreventExitStatus=3`),
and the README's table of commands lists them. A failed start has a code of its own, as
uvicorn's has, so a port taken or a store of a newer release reads differently from a service
that ran and then stopped on a failure.
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_FAILURE = 1
"""The command did not do what it was asked; for `run`, a bus or a feature died while serving."""
EXIT_USAGE = 2
"""Arguments that don't make sense (argparse exits with 2 for its own usage errors too)."""
EXIT_CONFIG = 3
"""A configuration that does not validate: restarting won't fix it, the unit leaves it down."""
EXIT_STARTUP = 4
"""`run` or `demo` could not start: a port taken or an address not of this machine, two
listeners on one port or a TLS file that can't be used (`gateway.config.startup`), a store of a
newer release or held by another gateway. Restarted by the unit: the port may be free on the
next try."""
EXIT_INTERRUPTED = 130
"""Ctrl-C in a command that is not the service (128 + SIGINT, as a shell reports it)."""
EXIT_BROKEN_PIPE = 141
"""The reader of the output went away (`invt-gateway ... | head`): 128 + SIGPIPE, as a shell
reports a tool that SIGPIPE ended, and nothing on stderr."""
