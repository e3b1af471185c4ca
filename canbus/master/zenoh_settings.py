"""The ``[zenoh]`` table of a host config (and of a reader's), checked, and the Zenoh
configuration it stands for.

Every field is optional; the defaults expose nothing beyond the machine: a peer that
listens on ``tcp/127.0.0.1:7447`` only, multicast scouting off, the admin space off.
A bad value fails at load with one line naming the field (``zenoh.listen[0]: ...``).
Paths (certificates, ``config_file``) are relative to the config file. Parsing needs no
Zenoh; :meth:`ZenohSettings.zenoh_config` imports it.
"""

from __future__ import annotations

import json
import re
import socket
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from skin.errors import ConfigError, SkinError
from skin.inputs import fields

DEFAULT_PREFIX = "canskin"

_CHUNK = re.compile(r"[^/*$?#\s]+")


def key_chunk_problem(name: str) -> str | None:
    """Why ``name`` cannot be one chunk of a key expression (None: it can)."""
    if not name:
        return "must not be empty"
    if not _CHUNK.fullmatch(name):
        return f"{name!r} holds a character a Zenoh key chunk cannot ('/', '*', '$', '?', " \
               "'#' or white space)"
    if name.startswith("@"):
        return f"{name!r} starts with '@' (Zenoh's verbatim chunks)"
    return None


def prefix_problem(prefix: str) -> str | None:
    """Why ``prefix`` cannot lead every key (None: it can); it may hold several chunks."""
    for chunk in prefix.split("/"):
        problem = key_chunk_problem(chunk)
        if problem is not None:
            return problem
    return None


if TYPE_CHECKING:
    import zenoh

MODES = ("peer", "client", "router")
DEFAULT_PORT = 7447
DEFAULT_LISTEN = (f"tcp/127.0.0.1:{DEFAULT_PORT}",)
DEFAULT_CONNECT = (f"tcp/127.0.0.1:{DEFAULT_PORT}",)  # a reader's
TLS_KEYS = ("root_ca_certificate", "listen_certificate", "listen_private_key",
            "connect_certificate", "connect_private_key")
TLS_FLAGS = ("enable_mtls", "verify_name_on_connect")
_ENDPOINT = re.compile(r"[a-z][a-z0-9-]*/\S+")
_DEFAULT_OPTIONS: Mapping[str, Any] = MappingProxyType({
    "adminspace/enabled": False,
    # batches a link holds for the forces' priority (Zenoh's default 2): a reader's link
    # rides out a publishing host or network stalled for a moment instead of dropping
    "transport/link/tx/queue/size/data_high": 8,
})
_FIELDS = ("enabled", "mode", "listen", "connect", "scouting", "prefix", "host", "queue_size",
           "stats_period_s", "express", "tls", "config_file", "options")


@dataclass(frozen=True)
class ZenohSettings:
    """Where and how a host publishes (or a reader reads) on Zenoh."""

    enabled: bool = True
    mode: str = "peer"
    listen: tuple[str, ...] | None = None  # None: DEFAULT_LISTEN for a host, none for a reader
    connect: tuple[str, ...] = ()
    scouting: bool = False  # multicast scouting
    prefix: str = DEFAULT_PREFIX
    host: str = ""  # "": this machine's name
    queue_size: int = 4096  # samples the publisher holds when Zenoh or a reader is slow
    stats_period_s: float = 1.0
    express: bool = False  # True: each force sample leaves at once, never batched by Zenoh
    tls: Mapping[str, str | bool] = field(default_factory=dict)
    config_file: Path | None = None  # a Zenoh JSON5 config the fields above go over
    options: Mapping[str, Any] = field(default_factory=dict)  # Zenoh config paths -> values

    @property
    def host_name(self) -> str:
        return self.host or default_host_name()

    def listen_endpoints(self, *, reader: bool = False) -> tuple[str, ...]:
        """Where the session listens: ``listen``, else none for a reader or a client and
        ``DEFAULT_LISTEN`` for a host."""
        if self.listen is not None:
            return self.listen
        return () if reader or self.mode == "client" else DEFAULT_LISTEN

    def connect_endpoints(self, *, reader: bool = False) -> tuple[str, ...]:
        """Where the session connects: ``connect``, else, for a reader that listens on
        nothing, ``DEFAULT_CONNECT`` (this machine's host)."""
        if self.connect or not reader or self.listen_endpoints(reader=True):
            return self.connect
        return DEFAULT_CONNECT

    def zenoh_config(self, *, reader: bool = False) -> zenoh.Config:
        """The Zenoh configuration: ``config_file`` (if any), then ``options``, then the
        fields. A reader's default is to connect to ``DEFAULT_CONNECT`` and listen on
        nothing; a host's to listen on ``DEFAULT_LISTEN``."""
        import zenoh

        config = (zenoh.Config.from_file(str(self.config_file)) if self.config_file
                  else zenoh.Config())
        for key, value in self.options.items():
            config.insert_json5(key, json.dumps(value))
        config.insert_json5("mode", json.dumps(self.mode))
        config.insert_json5("listen/endpoints",
                            json.dumps(list(self.listen_endpoints(reader=reader))))
        config.insert_json5("connect/endpoints",
                            json.dumps(list(self.connect_endpoints(reader=reader))))
        config.insert_json5("scouting/multicast/enabled", json.dumps(self.scouting))
        for key, value in _DEFAULT_OPTIONS.items():
            if key not in self.options:
                config.insert_json5(key, json.dumps(value))
        for key, value in self.tls.items():
            config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
        return config


class ZenohError(SkinError, RuntimeError):
    """Zenoh could not do what was asked (open a session, declare a publisher)."""


def require_zenoh(flag: str = "zenoh") -> None:
    """Refuse at once, naming ``flag``, when eclipse-zenoh is not installed."""
    try:
        import zenoh  # noqa: F401
    except ImportError as err:
        raise ConfigError(flag, "needs eclipse-zenoh: pip install 'canskin[zenoh]'") from err


def open_zenoh(settings: ZenohSettings, *, reader: bool = False) -> zenoh.Session:
    """A Zenoh session for ``settings``; :class:`ZenohError` in one line if it cannot open."""
    import zenoh

    try:
        return zenoh.open(settings.zenoh_config(reader=reader))
    except zenoh.ZError as err:
        where = ", ".join([*(f"listen {e}" for e in settings.listen_endpoints(reader=reader)),
                           *(f"connect {e}"
                             for e in settings.connect_endpoints(reader=reader))]) or "none"
        raise ZenohError(f"zenoh: cannot open a session ({where}): {err}") from err


def default_host_name() -> str:
    """This machine's name as one key chunk (characters a key cannot hold become '-')."""
    name = re.sub(r"[/*$?#\s]", "-", socket.gethostname()).lstrip("@") or "host"
    return name


def zenoh_settings_from_table(table: Any, *, base: Path = Path("."), where: str = "zenoh",
                              buses: tuple[str, ...] = ()) -> ZenohSettings:
    """Check a parsed ``[zenoh]`` table; ``buses``: the bus names, which become key chunks."""
    if not isinstance(table, dict):
        raise ConfigError(where, "must be a table ([zenoh])")
    fields.known_keys(table, _FIELDS, where)
    kwargs: dict[str, Any] = {}
    for key in ("enabled", "scouting", "express"):
        if key in table:
            kwargs[key] = fields.boolean(table[key], f"{where}.{key}")
    if "mode" in table:
        kwargs["mode"] = fields.choice(table["mode"], MODES, f"{where}.mode")
    for key in ("listen", "connect"):
        if key in table:
            kwargs[key] = check_endpoints(table[key], f"{where}.{key}")
    if "prefix" in table:
        prefix = fields.text(table["prefix"], f"{where}.prefix")
        if (problem := prefix_problem(prefix)) is not None:
            raise ConfigError(f"{where}.prefix", problem)
        kwargs["prefix"] = prefix
    if "host" in table:
        host = fields.text(table["host"], f"{where}.host")
        if (problem := key_chunk_problem(host)) is not None:
            raise ConfigError(f"{where}.host", problem)
        kwargs["host"] = host
    if "queue_size" in table:
        kwargs["queue_size"] = fields.integer(table["queue_size"], f"{where}.queue_size", 1,
                                              10**7)
    if "stats_period_s" in table:
        kwargs["stats_period_s"] = fields.number(table["stats_period_s"],
                                                 f"{where}.stats_period_s", above=0.0, unit="s")
    if "tls" in table:
        kwargs["tls"] = _tls(table["tls"], f"{where}.tls", base)
    if "config_file" in table:
        kwargs["config_file"] = _file(table["config_file"], f"{where}.config_file", base)
    if "options" in table:
        options = table["options"]
        if not isinstance(options, dict):
            raise ConfigError(f"{where}.options", "must be a table of Zenoh config paths "
                              "(e.g. \"transport/link/tx/queue/size/data\" = 8)")
        kwargs["options"] = dict(options)
    settings = ZenohSettings(**kwargs)
    for i, name in enumerate(buses):
        if (problem := key_chunk_problem(name)) is not None:
            raise ConfigError(f"buses[{i}].name", f"is a Zenoh key chunk: {problem}")
    return settings


def with_overrides(settings: ZenohSettings, **changes: Any) -> ZenohSettings:
    """A copy with the fields a command line gave (None: not given)."""
    return replace(settings, **{k: v for k, v in changes.items() if v is not None})


def check_endpoints(value: Any, where: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list):
        raise ConfigError(where, f"must be a list of endpoints like \"tcp/127.0.0.1:7447\", "
                          f"got {type(value).__name__}")
    out = []
    for k, item in enumerate(value):
        endpoint = fields.text(item, f"{where}[{k}]")
        if not _ENDPOINT.fullmatch(endpoint):
            raise ConfigError(f"{where}[{k}]", f"{endpoint!r} is not an endpoint "
                              "(PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447, tls/host:7447)")
        out.append(endpoint)
    return tuple(out)


def _file(value: Any, where: str, base: Path) -> Path:
    path = Path(fields.text(value, where))
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise ConfigError(where, f"no such file {str(path)!r}")
    return path


def _tls(table: Any, where: str, base: Path) -> dict[str, str | bool]:
    if not isinstance(table, dict):
        raise ConfigError(where, "must be a table ([zenoh.tls])")
    fields.known_keys(table, TLS_KEYS + TLS_FLAGS, where)
    out: dict[str, str | bool] = {}
    for key, value in table.items():
        if key in TLS_KEYS:
            out[key] = str(_file(value, f"{where}.{key}", base))
        else:
            out[key] = fields.boolean(value, f"{where}.{key}")
    for cert, key in (("listen_certificate", "listen_private_key"),
                      ("connect_certificate", "connect_private_key")):
        if (cert in out) != (key in out):
            missing = key if cert in out else cert
            raise ConfigError(f"{where}.{missing}", f"missing: {cert} and {key} go together")
    return out
