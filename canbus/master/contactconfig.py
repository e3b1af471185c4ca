"""The host config's contact keys: ``[contact]`` (every patch) and ``patches[].contact``
(one patch's own values of any of them), checked into :class:`skin.contact.ContactParams`;
and each patch's :class:`~canbus.master.contact.PatchContact` built from them.

```toml
[contact]                   # the defaults; enabled = false: no contact summary, no TPDO 8
taxel_contact_N = 0.12
onset_N = 0.3
release_N = 0.2
friction = 0.5
near_slip_margin = 0.2

[[patches]]
node_id = 1
position_m = [0.0, 0.0]
orientation_deg = 90.0      # the patch frame turned about the skin's normal
contact = { friction = 0.8 }
```
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Protocol

from canbus.master.contact import PatchContact
from skin.constants import DEFAULT_CONSTANTS, SensorConstants
from skin.contact import ContactParams, PatchGeometry
from skin.errors import ConfigError
from skin.inputs import fields
from skin.placement import PatchPlacement

PARAM_KEYS = tuple(f.name for f in dataclasses.fields(ContactParams))


def contact_from_table(table: Any, where: str, base: ContactParams | None
                       ) -> ContactParams | None:
    """``[contact]`` (``where`` = "contact", with ``enabled``) or a patch's ``contact``
    table over ``base``; None when the summary is off."""
    if not isinstance(table, Mapping):
        raise ConfigError(where, "must be a table of contact thresholds")
    keys = (*PARAM_KEYS, "enabled") if where == "contact" else PARAM_KEYS
    fields.known_keys(table, keys, where)
    enabled = fields.boolean(table.get("enabled", True), f"{where}.enabled")
    if not enabled or base is None:
        if where != "contact" and base is None:
            raise ConfigError(where, "the contact summary is off ([contact] enabled = false)")
        return None
    values = {key: fields.number(table[key], f"{where}.{key}") for key in PARAM_KEYS
              if key in table}
    try:
        return dataclasses.replace(base, **values)
    except ConfigError as err:
        raise ConfigError(f"{where}.{err.field}", err.problem) from err


def check_orientation(value: float, where: str) -> float:
    if not math.isfinite(value):
        raise ConfigError(where, f"must be a finite angle in degrees, got {value!r}")
    return value


class PatchPlace(Protocol):
    """What the contact judge reads of a patch's config (``hostconfig.PatchConfig``)."""

    @property
    def constants(self) -> SensorConstants | None: ...
    @property
    def position_m(self) -> tuple[float, float] | None: ...
    @property
    def orientation_deg(self) -> float: ...
    @property
    def contact(self) -> ContactParams | None: ...
    @property
    def placement(self) -> PatchPlacement | None: ...


class HostContact(Protocol):
    """The host config's contact thresholds (``hostconfig.HostConfig.contact``)."""

    @property
    def contact(self) -> ContactParams | None: ...


def patch_contact(patch: PatchPlace, config: HostContact) -> PatchContact | None:
    """The patch's contact judge: its geometry (pitch from its ``constants``, else the
    default patch's; the host takes the pitch the patch reports when it sets it up) and
    its thresholds; None when the config turns the summary off."""
    if config.contact is None:
        return None
    constants = patch.constants or DEFAULT_CONSTANTS
    geometry = PatchGeometry(constants.taxel_pitch_m, patch.position_m or (0.0, 0.0),
                             patch.orientation_deg)
    return PatchContact(geometry, patch.contact or config.contact, patch.placement)


def take_pitch(contact: PatchContact | None, constants: SensorConstants) -> None:
    """The taxel pitch a patch reports (0x2003) into its contact judge's geometry."""
    if contact is not None and contact.geometry.pitch_m != constants.taxel_pitch_m:
        contact.geometry = dataclasses.replace(contact.geometry,
                                               pitch_m=constants.taxel_pitch_m)
