"""The memory budget: what one canskin process may allocate for one request or file.

Sizes declared inside files (array headers, compressed lengths) and requests on the
command line (samples of a dataset, hidden nodes of a network) are checked against it
before anything is allocated, so a hostile file or a typo is refused with the figure
instead of eating the machine's memory. The budget is half the machine's physical memory
(less if the process has an address-space limit), or ``SKIN_MEMORY_BUDGET`` (bytes, or
with a k, M, G or T suffix: powers of 1024).
"""

from __future__ import annotations

import os
import re
import resource

from skin.errors import ConfigError

ENV = "SKIN_MEMORY_BUDGET"
SHARE = 0.5
_SIZE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([kKmMgGtT]?)[iI]?[bB]?\s*")
_UNITS = " KMGT"


def parse_size(text: str) -> int:
    """``1000``, ``64k``, ``1.5G`` (powers of 1024) as bytes; ValueError otherwise."""
    match = _SIZE.fullmatch(text)
    if match is None:
        raise ValueError(f"not a size in bytes: {text!r} (e.g. 1000000, 64k, 10M, 1G)")
    return int(float(match[1]) * 1024 ** _UNITS.index(match[2].upper() or " "))


def physical_memory() -> int:
    """The machine's physical memory in bytes (0 if the platform does not say)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 0


def memory_budget() -> int:
    """Bytes one request or file may need (see the module's docstring)."""
    given = os.environ.get(ENV)
    if given:
        try:
            return parse_size(given)
        except ValueError as err:
            raise ConfigError(ENV, str(err)) from err
    budget = int(SHARE * physical_memory()) or 4 << 30
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        budget = min(budget, int(SHARE * soft))
    return budget


def size_text(nbytes: float) -> str:
    """``2.7 GiB``, ``512 KiB``, ``12 B``."""
    value = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if value < 1024 or unit == "TiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    raise AssertionError("unreachable")


def require_memory(nbytes: float, what: str, field: str, *, source: str | None = None) -> None:
    """ConfigError naming ``field`` when ``what`` needs more than the budget."""
    budget = memory_budget()
    if nbytes > budget:
        raise ConfigError(field, f"{what} needs {size_text(nbytes)} of memory, more than the "
                          f"budget of {size_text(budget)} (half this machine's memory; "
                          f"{ENV} sets it)", source=source)
