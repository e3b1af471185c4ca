"""A bit-timed CAN / CAN FD bus: python-can's interface ``timed`` (docs/timedbus.md).

Modules: ``wire`` (the shared wire of a channel, run by whoever waits on it), ``channels`` (the
registry of this process's wires), ``bus`` (``TimedBus``, the
python-can interface), ``node`` (a bus instance's queues and error counters), ``faults``
(fault confinement and injected bit errors), ``stats`` (the statistics API), ``message``
(message copies), ``errors``.
"""

from canbus.timed.bus import TimedBus
from canbus.timed.channels import open_channels
from canbus.timed.errors import TimedBusConfigError, TimedBusError
from canbus.timed.stats import NodeStats, WireStats

__all__ = ["NodeStats", "TimedBus", "TimedBusConfigError", "TimedBusError", "WireStats",
           "open_channels"]
