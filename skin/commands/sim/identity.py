"""``skin sim run``'s patches as a lab gets them: serial numbers, LSS, non-volatile state.

* ``--serial-base B``: patch k of the scene (node-ID k) has serial number B + k (0x1018
  sub 4; default 0, so serial number = node-ID);
* ``--unconfigured``: every patch starts with node-ID 0xFF, sends nothing and waits for a
  master's LSS (CiA 305) to give it a node-ID (``skin lss``, or a host with ``lss``);
* ``--state-dir DIR``: each patch keeps its non-volatile store in
  ``DIR/patch-<serial>.json`` (``canbus.device.nv_store``): what LSS "store configuration"
  and 0x1010 "save" kept is there again after a restart (a stored node-ID wins over
  ``--unconfigured``). Without it the store lives as long as the process.
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sim import Scene


def add_identity_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--unconfigured", action="store_true",
                        help="every patch starts with node-ID 0xFF and waits for LSS (CiA 305)")
    from skin.commands.common import argtypes

    parser.add_argument("--serial-base", type=argtypes.serial, default=0, metavar="B",
                        help="patch k has serial number B + k (0x1018 sub 4; default 0)")
    parser.add_argument("--state-dir", metavar="DIR",
                        help="keep each patch's non-volatile store (LSS store, 0x1010 save) "
                             "in DIR/patch-<serial>.json across restarts")


def patch_identities(args: argparse.Namespace, scene: Scene) -> dict[str, Any]:
    """The PatchServer keyword arguments of the flags: serials, unconfigured, the stores."""
    from canbus.device.nv_store import NvStore
    from skin.errors import ConfigError

    serials = [args.serial_base + int(n) for n in scene.node_ids]
    if serials and serials[-1] > 0xFFFF_FFFF:
        raise ConfigError("--serial-base", f"serial numbers up to {serials[-1]:#x} do not fit "
                                           "UNSIGNED32")
    out: dict[str, Any] = {"serials": serials, "unconfigured": args.unconfigured}
    if args.state_dir:
        folder = Path(args.state_dir)
        if folder.exists() and not folder.is_dir():
            raise ConfigError("--state-dir", f"{folder} is not a directory")
        out["nv"] = functools.partial(NvStore.in_dir, folder, "patch")
    return out

