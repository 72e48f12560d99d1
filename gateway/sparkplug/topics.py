"""The Sparkplug B topics of one edge node (specification 3.0, "Topic Namespace").

| topic                                       | dir | what                                   |
|---------------------------------------------|-----|----------------------------------------|
| spBv1.0/<group>/NBIRTH/<node>               | out | the node's birth: bdSeq, Node Control  |
| spBv1.0/<group>/NDEATH/<node>               | out | the last will (and a clean stop)       |
| spBv1.0/<group>/NCMD/<node>                 | in  | "Node Control/Rebirth"                 |
| spBv1.0/<group>/DBIRTH/<node>/<drive>       | out | a drive's metrics, names and aliases   |
| spBv1.0/<group>/DDATA/<node>/<drive>        | out | what changed, by alias                 |
| spBv1.0/<group>/DDEATH/<node>/<drive>       | out | the drive went offline                 |
| spBv1.0/<group>/DCMD/<node>/<drive>         | in  | a command, set-point or point write    |
| spBv1.0/STATE/<primary_host_id>             | in  | the primary host: online or offline    |
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

NAMESPACE: Final = "spBv1.0"


@dataclass(frozen=True, slots=True)
class SparkplugTopics:
    group_id: str
    edge_node_id: str

    def node(self, kind: str) -> str:
        return f"{NAMESPACE}/{self.group_id}/{kind}/{self.edge_node_id}"

    def device(self, kind: str, device: str) -> str:
        return f"{self.node(kind)}/{device}"

    @property
    def device_commands(self) -> str:
        """The subscription for every drive's DCMD."""
        return self.device("DCMD", "+")

    def device_of(self, topic: str) -> str | None:
        """The device a DCMD topic names; None for any other topic."""
        prefix = self.node("DCMD") + "/"
        if topic.startswith(prefix) and "/" not in topic[len(prefix) :]:
            return topic[len(prefix) :]
        return None


def host_state(host_id: str) -> str:
    """The primary host application's STATE topic (3.0; 2.2's had no `spBv1.0/` in front)."""
    return f"{NAMESPACE}/STATE/{host_id}"
