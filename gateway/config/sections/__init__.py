"""The models of the file's sections, one class per section (and per item of a list), each
validating its own keys: ranges, formats, files that must be readable, an unknown key refused.
One module per subject of the file:

    section     what every section shares (`Section`), and the check of a named file
    values      how the file writes unit ids, words, function codes and register ranges
    modbus_tcp  `modbus_tcp`: the Modbus-TCP server, its TLS listener, its access rules
    buses       `buses`: the RS-485 lines
    drives      `drives`: the drives and devices on the lines
    reports     report by exception, for a drive (`drives[].report`) and for all (`mqtt.report`)
    mqtt        `mqtt`: the broker connection, and Sparkplug B
    console     `console`: the operator's web console and its users
    opcua       `opcua`: the OPC UA server (its users are the console's)
    storage     `storage`: the local store
    monitoring  `metrics` and `logging`

What involves several sections (a drive's bus defined, unit ids unique) is in `cross_checks`;
the whole file's model is `schema.GatewayConfig`.
"""
