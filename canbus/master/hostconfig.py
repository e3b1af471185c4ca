"""The host manager's TOML config -> frozen dataclasses, checked before anything touches a bus.

Every error is a :class:`~skin.errors.ConfigError` naming the dotted field, e.g.
``patches[2].model: no such file 'm.msgpack'`` or ``patches[1].force_cob_ids[0]: 0x1C1
is also patches[0].force_node TPDO 1`` (the COB-ID check: :mod:`canbus.master.cobids`).
The buses, ``[bus]`` or ``[[buses]]``: :mod:`canbus.master.busconfig`. A model file is
read once, by the check, and the decoder it holds is kept in the checked config
(``PatchConfig.prototype``) for the host to use.

Example: ``examples/host.toml``; the format is documented in ``docs/host.md``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from canbus.master.busconfig import BusConfig, buses_from_dict
from canbus.master.cobids import check_cob_ids, restricted
from canbus.master.contactconfig import check_orientation, contact_from_table
from canbus.master.robotconfig import PLACEMENT_KEYS, Robot, placement_from_table, robot_from_table
from decoder.protocol import Decoder
from decoder.registry import decoder_class, load_decoder, needs_fitting
from skin.constants import R0_RANGE_OHM, TAXELS_PER_PATCH, SensorConstants
from skin.contact import ContactParams
from skin.errors import ConfigError, ModelFileError
from skin.inputs import fields
from skin.inputs.tomlfile import read_toml
from skin.placement import PatchPlacement

if TYPE_CHECKING:
    from canbus.master.zenoh_settings import ZenohSettings

MODES = ("z", "xyz")
POSITION_LIMIT_M = 1000.0
ANSWER_ORDERS = ("cob-id", "tpdo")
TPDO_COUNT = 7
FORCE_TPDO_COUNT = 8  # the force node's: TPDO 8 is the contact
FORCE_NODE_OFFSET = 64


@dataclass(frozen=True)
class PatchConfig:
    """One patch the host manages, and the force node that publishes its forces."""

    node_id: int
    decoder: str = ""  # a registered decoder name; "" = the model file's, else "analytic"
    model: Path | None = None  # a model file (msgpack) of that decoder
    mode: str = "xyz"  # the TPDO mapping the host writes: "z" (9 values) or "xyz" (27)
    force_node: int = 0  # 0 in the constructor means node_id + 64
    force_cob_ids: tuple[int, ...] | None = None  # the force node's TPDO 1..7 (or 1..8) COB-IDs
    constants: SensorConstants | None = None  # what the patch reports (0x2001, 0x2003)
    r0_ohm: tuple[float, ...] | None = None  # its R0 (0x2002): 27 values, or 3 (z, x, y)
    answer_order: str = "cob-id"  # how the patch orders the TPDOs of one answer ("tpdo")
    position_m: tuple[float, float] | None = None  # where the patch sits on the skin (views)
    orientation_deg: float = 0.0  # its frame turned about the skin's normal (contact.md)
    contact: ContactParams | None = None  # its own contact thresholds (None: the host's)
    placement: PatchPlacement | None = None  # its link and pose on the robot (docs/robot.md)
    bus: str = ""  # the bus the patch is on ("": the host's first bus)
    force_bus: str = ""  # the bus its force node publishes on ("": the patch's)
    serial: int | None = None  # LSS: the patch with this serial number gets node_id
    prototype: Decoder | None = field(default=None, compare=False, repr=False)
    """The model file's decoder, read once when the config was checked."""

    def __post_init__(self) -> None:
        if self.force_node == 0:
            object.__setattr__(self, "force_node", self.node_id + FORCE_NODE_OFFSET)

    @property
    def pillars(self) -> int:
        return 1 if self.mode == "z" else 3


@dataclass(frozen=True)
class DriftConfig:
    """Baseline-drift tracking: an EMA of the resistance of taxels not in contact."""

    time_constant_s: float = 30.0
    contact_N: float = 0.1  # a taxel with |F| above this is in contact: its baseline freezes


@dataclass(frozen=True)
class HostConfig:
    patches: tuple[PatchConfig, ...]
    sync_period_ms: float = 10.0
    sync_window_ms: float = 0.0  # 0 in the constructor means 80 % of the period
    sync_counter: bool = True
    heartbeat_ms: int = 100  # written to every patch's 0x1017; lost after ~1.5 periods
    force_heartbeat_ms: int = 1000
    sdo_timeout_ms: int = 1000
    scan: bool = True
    scan_ms: int = 200
    other_nodes: tuple[int, ...] = ()
    tare_threshold_N: float = 0.05
    queue_size: int = 1024
    listen_only: bool = False  # follow another master's patches; transmit nothing
    sync: str = "produce"  # "external": follow the SYNC another master produces
    lss: str = ""  # "auto": patches waiting for LSS get the next free node-IDs
    lss_store: bool = False  # LSS store configuration after each assignment
    state_dir: str = ""  # the force nodes' non-volatile stores ("": in memory)
    drift: DriftConfig | None = None
    contact: ContactParams | None = field(default_factory=ContactParams)  # None: no summary
    buses: tuple[BusConfig, ...] = (BusConfig(),)
    zenoh: ZenohSettings | None = None  # [zenoh]: publish on Zenoh (canbus.master.zenoh_settings)
    source: str = field(default="<config>", compare=False)
    checked: bool = field(default=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.sync_window_ms == 0.0:
            object.__setattr__(self, "sync_window_ms", 0.8 * self.sync_period_ms)

    def patch(self, node_id: int) -> PatchConfig:
        for patch in self.patches:
            if patch.node_id == node_id:
                return patch
        raise KeyError(node_id)

    def check(self) -> HostConfig:
        """Every check of :func:`load_host_config`; returns the config with decoder names
        resolved (``""`` -> the model file's name or ``"analytic"``), model files read once
        (``PatchConfig.prototype``) and every patch placed on a bus. A checked config is
        returned as it is."""
        if self.checked:
            return self
        patches = tuple(_check_patch(p, f"patches[{i}]", self.buses)
                        for i, p in enumerate(self.patches))
        return _checked(replace(self, patches=patches))

    def bus(self, name: str) -> BusConfig:
        for bus in self.buses:
            if bus.name == name:
                return bus
        raise KeyError(name)

    @property
    def sync_following(self) -> bool:
        """SYNC comes from another master (listen-only, or ``sync = "external"``)."""
        return self.listen_only or self.sync == "external"


def load_host_config(path: str | os.PathLike[str]) -> HostConfig:
    """Read and check a host config file; model paths are relative to the file's folder.
    Every error names the file and the dotted field."""
    where = os.fspath(path)
    data = read_toml(path, "config")
    try:
        return host_config_from_dict(data, base=Path(path).parent, source=where)
    except ConfigError as err:
        raise err.in_file(where) from err


def host_config_from_dict(data: Mapping[str, Any], *, base: Path = Path("."),
                          source: str = "<config>") -> HostConfig:
    """Validate a parsed TOML document into a :class:`HostConfig`."""
    if not isinstance(data, Mapping):
        raise ConfigError("config", f"must be a table, got {fields.shown(data)}")
    fields.known_keys(data, ("host", "drift", "contact", "patches", "bus", "buses", "zenoh",
                             "robot"), "")
    host = data.get("host", {})
    if not isinstance(host, dict):
        raise ConfigError("host", "must be a table ([host])")
    fields.known_keys(host, _HOST_FIELDS, "host")
    kwargs: dict[str, Any] = {}
    for key, value in host.items():
        kind = _HOST_FIELDS[key]
        if key == "other_nodes":
            values = fields.array(value, "host.other_nodes", len(fields.NODE_IDS))
            kwargs[key] = tuple(fields.node_id(v, f"host.other_nodes[{k}]")
                                for k, v in enumerate(values))
        elif key in HOST_RANGES:
            low, high = HOST_RANGES[key]
            kwargs[key] = fields.integer(value, f"host.{key}", int(low), int(high)) \
                if kind is int else fields.number(value, f"host.{key}", high=high, above=low)
        else:
            kwargs[key] = fields.typed(value, kind, f"host.{key}")
    if kwargs.get("state_dir"):  # relative to the config file, as model paths are
        kwargs["state_dir"] = str(base / kwargs["state_dir"])
    drift = data.get("drift")
    if drift is not None:
        if not isinstance(drift, dict):
            raise ConfigError("drift", "must be a table ([drift])")
        fields.known_keys(drift, DRIFT_RANGES, "drift")
        kwargs["drift"] = DriftConfig(**{k: fields.number(v, f"drift.{k}", high=DRIFT_RANGES[k],
                                                          above=0.0)
                                         for k, v in drift.items()})
    contact = contact_from_table(data.get("contact", {}), "contact", ContactParams())
    kwargs["contact"] = contact
    tables = data.get("patches")
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ConfigError("patches", "missing: list the patches as [[patches]] tables")
    if len(tables) > len(fields.NODE_IDS):
        raise ConfigError("patches", f"{len(tables)} patches; a bus has node-IDs 1..127")
    buses = buses_from_dict(data)
    robot = robot_from_table(data.get("robot"), base)
    patches = tuple(_patch(t, f"patches[{i}]", base, buses, contact, robot)
                    for i, t in enumerate(tables))
    if "zenoh" in data:
        from canbus.master.zenoh_settings import zenoh_settings_from_table

        kwargs["zenoh"] = zenoh_settings_from_table(data["zenoh"], base=base,
                                                    buses=tuple(b.name for b in buses))
    return _checked(HostConfig(patches=patches, source=source, buses=buses, **kwargs))


def _checked(config: HostConfig) -> HostConfig:
    _check_host(config)
    check_cob_ids(config)
    return replace(config, checked=True)


_HOST_FIELDS: Mapping[str, type] = MappingProxyType({
    "sync_period_ms": float, "sync_window_ms": float, "sync_counter": bool,
    "heartbeat_ms": int, "force_heartbeat_ms": int, "sdo_timeout_ms": int, "scan": bool,
    "scan_ms": int, "other_nodes": list, "tare_threshold_N": float, "queue_size": int,
    "listen_only": bool, "sync": str, "lss": str, "lss_store": bool, "state_dir": str,
})
LSS_MODES = ("", "auto")
HOST_RANGES: Mapping[str, tuple[float, float]] = MappingProxyType({
    "sync_period_ms": (0.0, 60_000.0), "sync_window_ms": (0.0, 60_000.0),
    "heartbeat_ms": (1, 0xFFFF), "force_heartbeat_ms": (0, 0xFFFF),
    "sdo_timeout_ms": (1, 600_000), "scan_ms": (0, 600_000), "tare_threshold_N": (0.0, 1e4),
    "queue_size": (1, 1_000_000),
})
"""The number fields of [host]: integers in low..high, floats above low and up to high."""
DRIFT_RANGES = MappingProxyType({"time_constant_s": 1e6, "contact_N": 1e4})
SYNC_MODES = ("produce", "external")
_PATCH_FIELDS = ("node_id", "decoder", "model", "mode", "force_node", "force_cob_ids",
                 "constants", "r0_ohm", "answer_order", "position_m", "bus", "force_bus",
                 "serial", "orientation_deg", "contact", *PLACEMENT_KEYS)
# What a patch reports about itself: 0x2001 (LSB) and 0x2003 (adc_bits is not reported).
CONSTANT_KEYS = ("resistance_lsb_ohm", "youngs_modulus_pa", "resistivity_ohm_m", "length_m",
                 "area_m2", "max_strain", "full_scale_force_N", "taxel_pitch_m")


def _patch(table: dict[str, Any], where: str, base: Path,
           buses: tuple[BusConfig, ...], contact: ContactParams | None,
           robot: Robot | None = None) -> PatchConfig:
    fields.known_keys(table, _PATCH_FIELDS, where)
    if "node_id" not in table:
        raise ConfigError(f"{where}.node_id", "missing")
    kwargs: dict[str, Any] = {"node_id": fields.node_id(table["node_id"], f"{where}.node_id")}
    for key in ("decoder", "mode", "answer_order", "bus", "force_bus"):
        if key in table:
            kwargs[key] = fields.text(table[key], f"{where}.{key}")
    if "force_node" in table:
        kwargs["force_node"] = fields.node_id(table["force_node"], f"{where}.force_node")
    if "serial" in table:
        kwargs["serial"] = fields.serial_number(table["serial"], f"{where}.serial")
    if "force_cob_ids" in table:
        values = fields.array(table["force_cob_ids"], f"{where}.force_cob_ids",
                              FORCE_TPDO_COUNT)
        kwargs["force_cob_ids"] = tuple(fields.cob_id(v, f"{where}.force_cob_ids[{k}]")
                                        for k, v in enumerate(values))
    if "model" in table:
        model = Path(fields.path(table["model"], f"{where}.model"))
        kwargs["model"] = model if model.is_absolute() else base / model
    if "constants" in table:
        kwargs["constants"] = _constants(table["constants"], f"{where}.constants")
    if "position_m" in table:
        values = table["position_m"]
        if not isinstance(values, list) or len(values) != 2:
            raise ConfigError(f"{where}.position_m", f"must be [x, y] in metres, got "
                              f"{fields.shown(values)}")
        kwargs["position_m"] = tuple(fields.number(v, f"{where}.position_m[{k}]",
                                                   -POSITION_LIMIT_M, POSITION_LIMIT_M)
                                     for k, v in enumerate(values))
    if "orientation_deg" in table:
        kwargs["orientation_deg"] = check_orientation(
            fields.number(table["orientation_deg"], f"{where}.orientation_deg"),
            f"{where}.orientation_deg")
    kwargs["placement"] = placement_from_table(table, where, robot)
    if "contact" in table:
        kwargs["contact"] = contact_from_table(table["contact"], f"{where}.contact", contact)
    if "r0_ohm" in table:
        values = fields.array(table["r0_ohm"], f"{where}.r0_ohm", 3 * TAXELS_PER_PATCH)
        kwargs["r0_ohm"] = tuple(fields.number(v, f"{where}.r0_ohm[{k}]", *R0_RANGE_OHM)
                                 for k, v in enumerate(values))
    patch = PatchConfig(**kwargs)
    return _check_patch(patch, where, buses)


def _constants(table: Any, where: str) -> SensorConstants:
    if not isinstance(table, dict):
        raise ConfigError(where, "must be a table of sensor constants")
    fields.known_keys(table, CONSTANT_KEYS, where)
    values = {key: fields.number(value, f"{where}.{key}") for key, value in table.items()}
    return SensorConstants.from_dict(values, where)


def _check_patch(patch: PatchConfig, where: str, buses: tuple[BusConfig, ...]) -> PatchConfig:
    fields.node_id(patch.node_id, f"{where}.node_id")
    fields.node_id(patch.force_node, f"{where}.force_node")
    fields.choice(patch.mode, MODES, f"{where}.mode")
    fields.choice(patch.answer_order, ANSWER_ORDERS, f"{where}.answer_order")
    if patch.serial is not None:
        fields.serial_number(patch.serial, f"{where}.serial")
    if patch.force_cob_ids is not None:
        if len(patch.force_cob_ids) not in (TPDO_COUNT, FORCE_TPDO_COUNT):
            raise ConfigError(f"{where}.force_cob_ids", f"must list {TPDO_COUNT} COB-IDs "
                              f"(TPDO 1..{TPDO_COUNT}; TPDO 8, the contact, then keeps its "
                              f"own) or {FORCE_TPDO_COUNT}, got {len(patch.force_cob_ids)}")
        for k, cob_id in enumerate(patch.force_cob_ids):
            if restricted(fields.cob_id(cob_id, f"{where}.force_cob_ids[{k}]")):
                raise ConfigError(f"{where}.force_cob_ids[{k}]",
                                  f"0x{cob_id:X} is not an 11-bit COB-ID a PDO may use")
    if patch.r0_ohm is not None:
        if len(patch.r0_ohm) not in (3, 3 * TAXELS_PER_PATCH):
            raise ConfigError(f"{where}.r0_ohm", "must list 27 values (taxel 0 z, x, y, taxel "
                              f"1 ...) or 3 (z, x, y of every taxel), got {len(patch.r0_ohm)}")
        for k, value in enumerate(patch.r0_ohm):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{where}.r0_ohm[{k}]", f"must be > 0 ohm, got {value!r}")
    return _check_decoder(_place(patch, where, buses), where)


def _place(patch: PatchConfig, where: str, buses: tuple[BusConfig, ...]) -> PatchConfig:
    """The patch with its bus and its force node's bus named."""
    names = [bus.name for bus in buses]
    bus = patch.bus or names[0]
    if bus not in names:
        raise ConfigError(f"{where}.bus", f"no bus {bus!r}; the buses: {', '.join(names)}")
    force_bus = patch.force_bus or bus
    if force_bus not in names:
        raise ConfigError(f"{where}.force_bus", f"no bus {force_bus!r}; the buses: "
                          f"{', '.join(names)}")
    return replace(patch, bus=bus, force_bus=force_bus)


def _check_decoder(patch: PatchConfig, where: str) -> PatchConfig:
    if patch.model is None:
        if patch.prototype is not None:
            raise ConfigError(f"{where}.model", "a decoder object needs the model file it was "
                              "read from")
        name = patch.decoder or "analytic"
        try:
            cls = decoder_class(name)
        except ConfigError as err:
            raise ConfigError(f"{where}.decoder", err.problem) from err
        if needs_fitting(cls):
            raise ConfigError(f"{where}.model", f"decoder {cls.name!r} must be fitted: give the "
                              "model file it was trained into")
        return replace(patch, decoder=name)
    if patch.prototype is not None:
        model = patch.prototype
    elif not patch.model.is_file():
        raise ConfigError(f"{where}.model", f"no such file {os.fspath(patch.model)!r}")
    else:
        try:
            model = load_decoder(patch.model)
        except ModelFileError as err:
            raise ConfigError(f"{where}.model", str(err)) from err
    if patch.decoder and patch.decoder != model.name:
        raise ConfigError(f"{where}.decoder", f"{patch.decoder!r} but the model file holds "
                          f"a {model.name!r} model")
    pillars = getattr(model, "pillars_", None)
    if pillars is not None and pillars != patch.pillars:
        raise ConfigError(f"{where}.mode", f"{patch.mode!r} reads {patch.pillars} pillar(s) "
                          f"but the model was fitted on {pillars}")
    return replace(patch, decoder=model.name, prototype=model)


def _check_host(config: HostConfig) -> None:
    if not config.patches:
        raise ConfigError("patches", "the host needs at least one [[patches]]")
    for name in ("sync_period_ms", "sync_window_ms", "tare_threshold_N"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(f"host.{name}", f"must be > 0, got {value!r}")
    fields.choice(config.sync, SYNC_MODES, "host.sync")
    if config.lss not in LSS_MODES:
        raise ConfigError("host.lss", f"must be \"auto\" or absent, got {config.lss!r}")
    serials: dict[int, int] = {}
    for i, patch in enumerate(config.patches):
        if patch.serial is not None and serials.setdefault(patch.serial, i) != i:
            raise ConfigError(f"patches[{i}].serial", f"0x{patch.serial:08X} is also "
                              f"patches[{serials[patch.serial]}].serial")
    if config.sync_window_ms > config.sync_period_ms:
        raise ConfigError("host.sync_window_ms", f"{config.sync_window_ms:g} is longer than "
                          f"the SYNC period {config.sync_period_ms:g}")
    for name, low in (("heartbeat_ms", 1), ("force_heartbeat_ms", 0), ("sdo_timeout_ms", 1),
                      ("scan_ms", 0), ("queue_size", 1)):
        value = getattr(config, name)
        if not low <= value <= (0xFFFF if name.endswith("heartbeat_ms") else 10**9):
            raise ConfigError(f"host.{name}", f"out of range: {value!r}")
    for i, node in enumerate(config.other_nodes):
        fields.node_id(node, f"host.other_nodes[{i}]")
    if config.drift is not None:
        for name in ("time_constant_s", "contact_N"):
            value = getattr(config.drift, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"drift.{name}", f"must be > 0, got {value!r}")
