"""The three-node NATS Server cluster of `gateway.instruments.nats_cluster` (what
`invt-gateway stress --cluster` runs on), for the suite: a test without nats-server is skipped,
saying so.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.instruments import nats_cluster as cluster
from gateway.instruments.nats_cluster import NatsNode, nats_server_path

__all__ = ["NatsNode", "nats_cluster", "nats_server_path"]


@contextlib.contextmanager
def nats_cluster(directory: Path, size: int = 3) -> Iterator[list[NatsNode]]:
    """`size` nodes routed to each other, each with JetStream and MQTT; stopped at the end."""
    if nats_server_path() is None:
        pytest.skip("nats-server not found: install the Debian package nats-server")
    with cluster.nats_cluster(directory, size) as nodes:
        yield nodes
