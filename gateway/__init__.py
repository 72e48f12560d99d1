"""invt-gateway: Modbus-TCP and MQTT to an RS-485 line of INVT drives."""

__version__ = "0.2.0"
"""The release: pyproject.toml reads it from here (one owner); CHANGELOG.md says what changed."""
