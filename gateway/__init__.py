"""invt-gateway: Modbus-TCP and MQTT to an RS-485 line of INVT drives."""

__version__ = "0.1.0"
