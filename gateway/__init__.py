"""invt-gateway: Modbus-TCP and MQTT to an RS-485 line of INVT drives."""

from gateway.compiled import choose_engine_room

__version__ = "0.2.0"
"""The release: pyproject.toml reads it from here (one owner); CHANGELOG.md says what changed."""

ENGINE_ROOM = choose_engine_room()
"""How the transaction's modules run: compiled by mypyc, or Python and why (gateway/compiled.py).
Decided here, before any of them is imported."""
