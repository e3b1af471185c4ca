"""The view's tests open virtual buses too: fail any test that leaves a channel open."""

from tests.canbus.conftest import _no_open_virtual_channels

__all__ = ["_no_open_virtual_channels"]
