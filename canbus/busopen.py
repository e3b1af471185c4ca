"""Open a python-can bus so that a failure is one line, and nothing of it is left behind.

python-can's interfaces fail in their own ways: ``OSError``, ``ValueError``,
``CanInterfaceNotImplementedError``, a ``socket.gaierror``, an ``AttributeError`` from a
missing driver; and a bus whose constructor failed half-way logs ``... was not properly
shut down`` whenever it is collected, long after the error was reported.
:func:`open_can_bus` turns any failure into one :class:`~skin.errors.BusError` naming the
bus and has the half-built bus collected on the spot, so that a caller that holds
python-can's log records back while it opens the bus (``skin.commands.common.logs.held_back``)
holds that one back too.
"""

from __future__ import annotations

import gc
import traceback
from collections.abc import Mapping
from typing import Any

import can

from skin.errors import BusError

_MAX_REASON = 300


def reason(err: BaseException) -> str:
    """``Type: message`` on one line, cut to a readable length."""
    text = " ".join(str(err).split())
    line = f"{type(err).__name__}: {text}" if text else type(err).__name__
    return line if len(line) <= _MAX_REASON else line[:_MAX_REASON] + "..."


def open_can_bus(kwargs: Mapping[str, Any], what: str) -> can.BusABC:
    """``can.Bus(**kwargs)``; a BusError ``cannot open <what>: <Type>: <reason>`` if it fails."""
    try:
        return can.Bus(**kwargs)
    except Exception as err:  # an interface may raise anything; all of it is "cannot open"
        problem = reason(err)
        traceback.clear_frames(err.__traceback__)  # frees the half-built bus now ...
        gc.collect()  # ... so that its "not properly shut down" is logged now, not later
        raise BusError(f"cannot open {what}: {problem}") from err


def configured_bus() -> dict[str, Any]:
    """The bus python-can's own configuration (files, ``CAN_INTERFACE``, ``CAN_CHANNEL``)
    names, checked and completed by ``can.util.load_config``: the keyword arguments of
    ``can.Bus``; empty when it names no interface (``load_config`` raises then). What the
    configuration sets, interface or not, as it sets it:
    ``skin.commands.common.busopen.python_can_settings``."""
    try:
        return dict(can.util.load_config())
    except Exception:  # python-can raises CanInterfaceNotImplementedError for "none"
        return {}


def configured_interface() -> str | None:
    """The interface python-can's own configuration names, or None."""
    interface = configured_bus().get("interface")
    return interface if isinstance(interface, str) else None
