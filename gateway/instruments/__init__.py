"""The instruments: what tests, demonstrates and measures the gateway, apart from the service.

- `simulator`: simulated INVT drives on a virtual RS-485 line (`invt-gateway simulate`), and the
  adapter effects of real hardware (bursts, glitches, echo);
- `bench`: the benchmark against the wire's physical limit (`invt-gateway bench`);
- `stress`: faults, hostile clients and outages under checked load (`invt-gateway stress`);
- `demo_broker`, `embedded_broker`: the demo's MQTT broker when none runs;
- `commands`: the `demo`, `simulate`, `bench` and `stress` sub-commands.

`invt-gateway run` never imports anything here, and the Docker image leaves this package out:
the service and the field tools a technician uses on real hardware are all it carries.
"""
