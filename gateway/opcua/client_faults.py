"""asyncua's log of what a client got wrong, made the gateway's kind of line: one warning, no
traceback, the same kind repeated once a minute with its count (`gateway.logs.repeated`).

A malformed or oversized message is the client's fault, not the gateway's: asyncua logs it
with `logger.exception` (a traceback per message: a fuzzing client writes the journal full)
and refuses it; here it becomes "OPC UA: a client's message refused: ...". asyncua's own INFO
lines (each connection made and lost) are left out unless the gateway logs at debug.
"""

from __future__ import annotations

import logging
from typing import Final

from gateway.logs import repeated

SOURCES: Final = (
    "asyncua.server.binary_server_asyncio",
    "asyncua.server.uaprocessor",
    "asyncua.uaprotocol",
)
CLIENT_FAULTS: Final = (
    "Exception raised while parsing message from client",
    "Exception raised while processing message from client",
    "Got malformed header",
    "Received request that exceed the transport limits",
    "Received an error message type",
    "Received an error: ",
    "Unsupported message type",
    "sending service fault response",
)
"""The starts of asyncua's lines about a client's message."""
WHY_MAX: Final = 200
REPEAT_SOURCE: Final = repeated("opcua:client_message")["repeat_source"]


class ClientFaults(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if record.levelno < logging.WARNING or not text.startswith(CLIENT_FAULTS):
            return True
        why = record.exc_info[1] if record.exc_info else None
        cause = f" ({type(why).__name__}: {str(why)[:WHY_MAX]})" if why is not None else ""
        record.msg, record.args = "OPC UA: a client's message refused: %s%s", (text, cause)
        record.exc_info, record.exc_text = None, None
        record.levelno, record.levelname = logging.WARNING, "WARNING"
        record.repeat_source = REPEAT_SOURCE
        return True


def install() -> None:
    """Once per process: a second server's start finds it there."""
    for name in SOURCES:
        logger = logging.getLogger(name)
        if not any(isinstance(f, ClientFaults) for f in logger.filters):
            logger.addFilter(ClientFaults())
    stack = logging.getLogger("asyncua")
    if stack.level == logging.NOTSET and logging.getLogger().level > logging.DEBUG:
        stack.setLevel(logging.WARNING)
