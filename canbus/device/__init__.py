"""The device side: a tactile patch as a CANopen node (object dictionary, SDO server, NMT
slave, heartbeat, EMCY, TPDOs) and a server of many patches fed by a signal source."""

from canbus.device.local_device import TPDO_COUNT, LocalDevice

__all__ = ["TPDO_COUNT", "LocalDevice"]
