"""``skin view --zenoh``: the whole skin from every host publishing on Zenoh.

A live source beside those of :mod:`skin.commands.view.sources`: one subscription to the
force samples of every host (or ``--key``), filed into the view from Zenoh's thread, and
one to the hosts' statistics, whose patch positions (``patches[].position_m`` of each
host's config) place the patches when no layout was given. Endpoints come from the
command line (default: this machine's ``tcp/127.0.0.1:7447``) or a reader's TOML with a
``[zenoh]`` table (``--zenoh-config``: TLS certificates, mode, prefix).
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canbus.master.zenoh_settings import ZenohSettings
    from canbus.zenoh.reader import Subscription
    from canbus.zenoh.schema import Sample
    from skin.commands.view.term import SkinView


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Zenoh (the forces every host publishes: docs/zenoh.md)")
    group.add_argument("--zenoh", nargs="*", metavar="ENDPOINT", default=None,
                       help="read the skin from Zenoh, connecting to ENDPOINTs (default "
                            "tcp/127.0.0.1:7447)")
    group.add_argument("--zenoh-config", metavar="READER.toml",
                       help="a TOML whose [zenoh] table is the reader's settings (connect, "
                            "tls, prefix, mode)")
    group.add_argument("--key", metavar="KEYEXPR",
                       help="the force samples to show (default: PREFIX/*/*/forces/*)")


def check_zenoh_arguments(args: argparse.Namespace) -> None:
    from skin.errors import ConfigError

    if args.zenoh is None:
        for flag, value in (("--zenoh-config", args.zenoh_config), ("--key", args.key)):
            if value is not None:
                raise ConfigError(flag, "goes with --zenoh")
        return
    if args.file:
        raise ConfigError("--zenoh", "reads live samples: no FILE with it")
    if args.decode:
        raise ConfigError("--decode", "decodes a bus: not with --zenoh")


def reader_settings(args: argparse.Namespace) -> ZenohSettings:
    from canbus.master.zenoh_settings import ZenohSettings, require_zenoh, zenoh_settings_from_table
    from skin.errors import ConfigError
    from skin.inputs.tomlfile import read_toml

    require_zenoh("--zenoh")
    settings = ZenohSettings()
    if args.zenoh_config:
        path = Path(args.zenoh_config)
        data = read_toml(path, "--zenoh-config")
        if "zenoh" not in data:
            raise ConfigError("--zenoh-config", f"{path}: has no [zenoh] table")
        try:
            settings = zenoh_settings_from_table(data["zenoh"], base=path.parent)
        except ConfigError as err:
            raise err.in_file(str(path)) from err
    if args.zenoh:
        from canbus.master.zenoh_settings import check_endpoints, with_overrides

        settings = with_overrides(settings, connect=check_endpoints(args.zenoh, "--zenoh"))
    return settings


class ZenohForces:
    """Every host's force samples on Zenoh, filed into a view (module docstring)."""

    def __init__(self, settings: ZenohSettings, key: str | None) -> None:
        self.settings = settings
        self.key = key
        self.subscription: Subscription | None = None
        self.hosts: set[str] = set()
        self.owners: dict[int, str] = {}
        self.positions: dict[int, tuple[float, float]] = {}
        self._stats: Any = None
        self._view: SkinView | None = None
        self._lock = threading.Lock()
        self._warned: set[tuple[int, str]] = set()

    def start(self, view: SkinView) -> None:
        from canbus.zenoh.reader import open_session, subscribe, subscribe_events

        self._view = view
        session = open_session(self.settings)
        try:
            self._stats = subscribe_events(self._on_event, session=session,
                                           prefix=self.settings.prefix)
            self.subscription = subscribe(self.key, settings=self.settings, session=session,
                                          ring=1, on_sample=self._on_sample)
        except BaseException:
            session.close()
            raise

    def _on_sample(self, sample: Sample) -> None:
        assert self._view is not None
        patch = sample.frame.patch
        owner = self.owners.setdefault(patch, sample.host)
        if owner != sample.host and (patch, sample.host) not in self._warned:
            self._warned.add((patch, sample.host))
            from skin.commands.common.logs import warn

            warn(f"warning: patch {patch} is published by hosts {owner} and {sample.host}; "
                 "shown as one (--key picks a host)")
        self.hosts.add(sample.host)
        self._view.update(sample.frame)

    def _on_event(self, key: str, fields: dict[str, Any]) -> None:
        """Place the patches where the hosts' configs put them (unless a layout was given)."""
        from skin.commands.view.layout import Layout

        view = self._view
        if not key.endswith("/stats") or view is None or view.layout.source not in ("row",
                                                                                      "zenoh"):
            return
        with self._lock:
            changed = False
            for patch in fields.get("patches", []):
                where = patch.get("position_m") if isinstance(patch, dict) else None
                if isinstance(where, list) and len(where) == 2:
                    place = (float(where[0]), float(where[1]))
                    changed |= self.positions.get(patch["patch"]) != place
                    self.positions[int(patch["patch"])] = place
            if changed:
                view.layout = Layout(dict(self.positions), view.layout.pitch_m, "zenoh")

    def stop(self) -> None:
        if self.subscription is None:
            return
        for subscriber in self._stats or ():
            subscriber.undeclare()
        session = self.subscription.session
        self.subscription.close()
        session.close()

    def received(self) -> int:
        return 0 if self.subscription is None else self.subscription.received

    def error(self) -> BaseException | None:
        return None

    def figures(self) -> dict[str, Any]:
        counters = {} if self.subscription is None else self.subscription.counters()
        return {"samples": counters.get("received", 0), "rejected": counters.get("rejected", 0),
                "hosts": sorted(self.hosts)}


def run_zenoh(args: argparse.Namespace, layout: Any, live: Any) -> int:
    """The live view of the skin on Zenoh, through the view's own ``live`` loop."""
    from skin.commands.view.live import SNAPSHOT_SECONDS

    settings = reader_settings(args)
    seconds = args.seconds
    if seconds is None and args.snapshot:
        seconds = SNAPSHOT_SECONDS
    source = ZenohForces(settings, args.key)
    where = "zenoh " + (", ".join(settings.connect) or "tcp/127.0.0.1:7447")
    return int(live(args, source, layout, seconds, where, lambda view, started:
                    f"{time.monotonic() - started:5.1f} s"))
