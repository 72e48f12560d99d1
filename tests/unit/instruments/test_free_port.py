"""`free_port`: the tests' and the bench's one way to a port for a listener they start."""

from __future__ import annotations

import socket

from gateway.instruments.bench.processes import free_port


def test_a_port_is_never_handed_out_twice() -> None:
    # Plain binds to port 0 gave the same port twice in a row about once in 5,000 pairs, and
    # among 2,000 of them dozens of repeats: a demo given one as its Modbus-TCP port and the
    # other as its MQTT port failed to start (CI, 2026-11-28).
    ports = [free_port() for _ in range(2000)]
    assert len(set(ports)) == len(ports)


def test_the_port_is_free_to_listen_on() -> None:
    port = free_port()
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", port))
        listener.listen()
