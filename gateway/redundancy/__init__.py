"""Two gateway boxes on one RS-485 line, one active and one standby, never two masters (issue
48): the role machine (`roles`), the standby's ear on the line (`listener`), the active's watch
for another master's frames (`watch`), what is told of them (`frames`), and their metrics.

    frames    which frames heard are requests (a master's), which are replies (a drive's)
    listener  a standby's port, opened only to listen: when the line was last heard
    watch     an active's line: a request it did not send is another master's
    roles     standby, listening, active: the changes asked on the control socket, the
              listening before a takeover, the demotion when another master is heard
    metrics   the role and its changes, the frames of another master heard, for /metrics
    fault_file  the box's fitness told to Keepalived at once (its `track_file`)
"""

from gateway.redundancy.roles import LineOwner, Redundancy, Role

__all__ = ["LineOwner", "Redundancy", "Role"]
