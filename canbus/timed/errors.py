"""Errors of the timed bus: canskin's and python-can's at once."""

from __future__ import annotations

import can

from skin.errors import BusError, SkinError


class TimedBusConfigError(SkinError, can.CanInitializationError, ValueError):
    """A timed bus cannot be opened as asked (bad option, or bitrates that disagree)."""

    def __init__(self, message: str) -> None:
        Exception.__init__(self, message)
        self.error_code = None


class TimedBusError(BusError, can.CanOperationError):
    """A timed bus refused an operation (closed bus, frame it cannot send, full queue)."""

    def __init__(self, message: str) -> None:
        Exception.__init__(self, message)
        self.error_code = None
