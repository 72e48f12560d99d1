"""Values polled while the edge node could not publish, as Sparkplug sees them: DDATA whose
metrics are `is_historical`, each with the time it was polled (specification 3.0,
"is_historical"), by alias; a gap the outage buffer could not hold is a null historical metric
of each at its start, so a historian shows "nothing known" there rather than a line drawn
across. No I/O: `publish` sends (the edge node's DDATA with its `seq`).

A drive that is being born (a rebirth, back online) gets its samples once its DBIRTH is out (a
DDATA before it is no Sparkplug: `payloads-ddata-order`); a drive offline now loses them.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Mapping

from gateway.poller import Poller
from gateway.sparkplug.metrics import DeviceMetrics
from gateway.sparkplug.payload import HistoricalMetric
from gateway.store.outage_rows import Gap, KeptSample

Publish = Callable[[str, list[HistoricalMetric]], Awaitable[None]]
"""A DDATA of these metrics for this drive."""


class HistoricalData:
    def __init__(
        self, devices: Mapping[str, DeviceMetrics], poller: Poller, publish: Publish
    ) -> None:
        self.devices = devices
        self.poller = poller
        self.publish = publish

    async def send(self, drive: str, samples: list[KeptSample]) -> bool:
        """One DDATA of `samples`; False: not now (the drive is being born)."""
        device = self.devices.get(drive)
        if device is None or not device.born:
            return device is None or self.poller.availability(drive) is False
        metrics = [
            HistoricalMetric(alias, datatype, value, int(sample.time * 1000))
            for sample in samples
            for alias, datatype, value in device.historical(sample.values)
        ]
        if metrics:
            await self.publish(drive, metrics)
        return True

    async def mark(self, gap: Gap) -> None:
        device = self.devices.get(gap.drive)
        if device is not None and device.born:
            at = int(gap.start * 1000)
            await self.publish(
                gap.drive, [HistoricalMetric(a, t, None, at) for a, t in device.declared()]
            )
