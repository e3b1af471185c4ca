"""Many patch nodes on one bus, fed by one signal source.

One SYNC subscription for all nodes: each SYNC hands each node its patch of the current
sample and sends the TPDOs that are due. Without ``event_rate_hz`` every SYNC reads the
next sample from the source; with it, a thread reads the source at that rate (the
source's own clock, which also serves event-driven TPDOs) and SYNC sends the latest
sample, so the source never runs faster than its rate. TPDO frames go straight to the
python-can bus (the data plane); canopen handles only NMT and SDO.
"""

from __future__ import annotations

import logging
import threading
import time

import can
import canopen
import numpy as np

from canbus.device.patch_node import (
    PatchNode,
    batch_frames_on_event,
    batch_frames_on_sync,
    batch_update,
)
from canbus.device.source import ResistanceSource
from canbus.txmessage import TxMessage
from skin.constants import DEFAULT_CONSTANTS, SensorConstants

logger = logging.getLogger(__name__)

SYNC_COB_ID = 0x080


class PatchServer:
    """The source's patches as :class:`PatchNode` s on ``network``; use as a context manager."""

    def __init__(self, network: canopen.Network, source: ResistanceSource, *,
                 mode: str | None = None, constants: SensorConstants = DEFAULT_CONSTANTS,
                 event_rate_hz: float = 0.0) -> None:
        self.network = network
        self.source = source
        mode = mode or ("z" if source.pillars == 1 else "xyz")
        self.nodes = [PatchNode(n, mode=mode, constants=constants, serial=n)
                      for n in source.node_ids]
        self.sync_count = 0
        self.samples = 0
        self.frames_sent = 0
        self._lock = threading.Lock()
        self._event_rate_hz = event_rate_hz
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._tick()  # nodes hold a real sample before anyone can read them
        for node in self.nodes:
            node.attach(self.network)
        self.network.subscribe(SYNC_COB_ID, self.on_sync)
        if self._event_rate_hz > 0:
            self._thread = threading.Thread(target=self._event_loop, daemon=True,
                                            name="patch-events")
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.network.unsubscribe(SYNC_COB_ID, self.on_sync)
        for node in self.nodes:
            node.detach()

    def __enter__(self) -> PatchServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """One SYNC: a new sample, then every node's synchronous TPDOs."""
        with self._lock:
            self.sync_count += 1
            if self._thread is None:
                self._tick()
            self._send(batch_frames_on_sync(self.nodes, self.sync_count, data[0] if data else 0))

    def _tick(self) -> None:
        sample = np.asarray(self.source.read(), dtype=np.float64)
        if len(sample) != len(self.nodes):
            raise ValueError(f"the source gave {len(sample)} patches, "
                             f"the server has {len(self.nodes)}")
        self.samples += 1
        batch_update(self.nodes, sample.reshape(len(self.nodes), 9, -1))

    def _event_loop(self) -> None:
        period = 1.0 / self._event_rate_hz
        deadline = time.monotonic()
        while not self._stop.is_set():
            deadline += period
            self._stop.wait(max(0.0, deadline - time.monotonic()))
            now = time.monotonic()
            with self._lock:
                self._tick()
                self._send(batch_frames_on_event(self.nodes, now))

    def _send(self, frames: list[tuple[int, bytes]]) -> None:
        bus = self.network.bus
        assert bus is not None, "the network is not connected"
        for cob_id, payload in frames:
            try:
                bus.send(TxMessage.frame(cob_id, payload))
            except can.CanError as err:
                logger.warning("TPDO 0x%03X not sent: %s", cob_id, err)
        self.frames_sent += len(frames)
