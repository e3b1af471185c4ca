"""Where ``skin run`` finds its host config when none is named: a documented search order.

1. ``$SKIN_HOST_CONFIG`` (a path), when set;
2. ``./host.toml`` in the working directory;
3. ``$XDG_CONFIG_HOME/canskin/host.toml`` (default ``~/.config/canskin/host.toml``);
4. ``/etc/canskin/host.toml`` (a service's place).

The first that exists is used; none is an error that lists where it looked.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV = "SKIN_HOST_CONFIG"


def candidates() -> list[Path]:
    """The places searched, in order."""
    out = []
    if os.environ.get(ENV):
        out.append(Path(os.environ[ENV]))
    out.append(Path("host.toml"))
    xdg = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    out.append(Path(xdg) / "canskin" / "host.toml")
    out.append(Path("/etc/canskin/host.toml"))
    return out


def find_config(given: str | None) -> Path:
    """``given``, or the first config found in the search order."""
    from skin.errors import ConfigError

    if given is not None:
        return Path(given)
    places = candidates()
    for place in places:
        if place.is_file():
            return place
    raise ConfigError("CONFIG", "none given and none found; looked for "
                      + ", ".join(str(p) for p in places))
