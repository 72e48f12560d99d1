"""Sparkplug B: the gateway as an edge node, each drive (and device) a Sparkplug device.

- `sparkplug_b.proto`: the payload as the specification defines it; `sparkplug_b_pb2` is what
  protoc makes of it (committed; `generate.sh` remakes it).
- `payload`: metrics to bytes and back (no I/O).
- `topics`: the `spBv1.0/<group>/<type>/<node>[/<device>]` names.
- `metrics`: each device's metrics: names, aliases, datatypes, properties, what changed.
- `commands`: DCMD metrics to the `/set` path's commands (checks, writes, events).
- `host`: the primary host application's `STATE`.
- `history`: values polled while the node could not publish, as historical DDATA.
- `edge_node`: `SparkplugNode`, the feature: births, deaths, data, commands, rebirth.
"""
