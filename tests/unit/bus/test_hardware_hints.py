"""What the log tells a technician to change when the line's hardware shows in the replies: for
bursts, the setting of the device server or of the FTDI adapter behind the port (its latency
timer found in sysfs, with its value now); for an echo, `echo: true`."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.bus import hardware_hints
from gateway.bus.hardware_hints import burst_hint, echo_hint, latency_timer_path

WHERE = "bus line1 (/dev/ttyUSB0)"


@pytest.fixture
def usb_serial(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A sysfs of usb-serial devices with one FTDI adapter, ttyUSB0, its timer at 16 ms (as
    /sys/bus/usb-serial/devices shows it; this machine has none)."""
    devices = tmp_path / "usb-serial" / "devices"
    (devices / "ttyUSB0").mkdir(parents=True)
    (devices / "ttyUSB0" / "latency_timer").write_text("16\n")
    monkeypatch.setattr(hardware_hints, "USB_SERIAL_SYSFS", devices)
    return devices


def test_bursts_behind_an_ftdi_adapter_name_its_latency_timer_and_its_value(
    usb_serial: Path, tmp_path: Path
) -> None:
    timer = usb_serial / "ttyUSB0" / "latency_timer"
    by_id = tmp_path / "usb-FTDI_FT232R-if00-port0"
    by_id.symlink_to("/dev/ttyUSB0")  # udev's stable name, a link to the device
    assert latency_timer_path("/dev/ttyUSB0") == timer
    assert latency_timer_path(str(by_id)) == timer
    hint = burst_hint(WHERE, str(by_id), 0.016)
    assert hint.startswith(f"{WHERE}: replies arrive in bursts (a silence of 16 ms inside one)")
    assert f"its latency timer (now 16 ms) can be set to 1 ms with `echo 1 > {timer}`" in hint


def test_bursts_behind_another_port_give_the_general_advice(usb_serial: Path) -> None:
    assert latency_timer_path("/dev/ttyS1") is None
    hint = burst_hint(WHERE, "/dev/ttyS1", 0.009)
    assert "a silence of 9 ms" in hint
    assert "/sys/bus/usb-serial/devices/<ttyUSBn>/latency_timer (16 ms by default)" in hint


def test_bursts_behind_a_serial_device_server_name_its_packing_interval() -> None:
    assert latency_timer_path("socket://10.0.0.5:4001") is None
    hint = burst_hint("bus line2 (socket://10.0.0.5:4001)", "socket://10.0.0.5:4001", 0.05)
    assert "A serial device server packs bytes into TCP segments" in hint
    assert "latency_timer" not in hint


def test_an_echo_says_to_set_echo_true_for_its_bus() -> None:
    hint = echo_hint(WHERE)
    assert hint.startswith(f"{WHERE}: this adapter echoes what the gateway sends")
    assert "set `echo: true` for this bus" in hint
