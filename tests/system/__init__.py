"""The system tests: the whole gateway, or the CLI as a subprocess, end to end, against real
sockets, a real pty serial line, real brokers and peers nobody here wrote. The rooms' own unit
tests are under tests/unit/."""
