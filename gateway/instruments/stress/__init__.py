"""`invt-gateway stress`: hostile conditions for a given time, and what the clients saw.

- `checked_load`: Modbus-TCP clients that know the drives' true values and check every answer.
- `processes`: the simulated line, the gateway and a Mosquitto broker as subprocesses that the
  scenario can unplug, kill and restart; their memory from /proc.
- `broker_watch`: an MQTT client that notes when the gateway says it is online.
- `scenario`: the run: line faults throughout, and one recovery after another.
- `report`: the table and the verdict.
- `soak`, `soak_clients`, `soak_faults`, `soak_report`: `--soak HOURS`, a plant's traffic
  compressed, its faults in rounds, the gateway sampled; `memory_growth` compares the
  gateway's tracemalloc snapshots.
- `history_load`: `--history`, months of history charted at once while SCADA reads.
- `opcua_fuzz`, `opcua_fuzz_load`: `--opcua-fuzz N`, malformed OPC UA messages to the
  endpoint while SCADA reads over Modbus-TCP.
"""
