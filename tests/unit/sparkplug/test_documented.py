"""Every Sparkplug topic the edge node uses is in the MQTT topic reference, in the form the
page writes them (`<group>`, `<node>`, `<drive>`), and so is every node metric it declares."""

from __future__ import annotations

from pathlib import Path

from gateway.sparkplug import edge_node
from gateway.sparkplug.topics import SparkplugTopics, host_state

PAGE = Path(__file__).resolve().parents[3] / "docs" / "pages" / "mqtt.md"


def test_every_sparkplug_topic_and_node_metric_is_documented() -> None:
    text = PAGE.read_text(encoding="utf-8")
    topics = SparkplugTopics("<group>", "<node>")
    made = [topics.node(kind) for kind in ("NBIRTH", "NDEATH", "NCMD")]
    made += [topics.device(kind, "<drive>") for kind in ("DBIRTH", "DDATA", "DDEATH", "DCMD")]
    made.append(host_state("<primary_host_id>"))
    missing = [topic for topic in made if f"`{topic}`" not in text]
    assert not missing, f"Sparkplug topics not in docs/pages/mqtt.md: {missing}"
    for metric in (edge_node.REBIRTH, edge_node.NEXT_SERVER, "bdSeq", "Node Info/gateway_id"):
        assert f"`{metric}`" in text, metric
