"""The OPC UA server (`opcua:`): the drives and devices for SCADA, MES and historians that speak
OPC UA, on asyncua and the gateway's own event loop.

    server          the feature: lifecycle, and the poller's values into the variables
    address_space   the nodes and their stable NodeIds
    values          DataTypes, UNECE units, DataValues
    command_path    writes and methods through MQTT's `/set` path (`Commands`)
    parameters      `Parameters/P00.03`...: read from the drive on demand, written as MQTT's
    drive_events    faults, limit alarms, a drive lost or back as OPC UA events
    bounds          monitored items per session
    client_faults   a client's malformed message as one warning line, no traceback
    logins          the console's users and roles
    certificates    the server's certificate, the clients' trusted and refused

Imported only when `opcua.enabled` (asyncua is the `opcua` extra).
"""
