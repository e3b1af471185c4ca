"""argparse types with ranges: every numeric option of every command uses one.

A value outside its range (``inf``, ``nan``, a negative count, an absurd size) is refused
by argparse, before the command does any work, in one line (``skin demo: error: argument
--seconds: ...``; exit status 2). Each factory returns a callable argparse uses as
``type=``; its name is what argparse's own messages call the value.

The python-can bus flags get theirs through :func:`add_bus_arguments` (its ``--bitrate``
and ``--data-bitrate``, and a ``--filter`` that says which filter it cannot read).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

from skin.inputs.budget import parse_size, size_text

YEAR_S = 365 * 24 * 3600
MAX_SEED = 2**63 - 1


def _named(name: str, check: Callable[[str], Any]) -> Callable[[str], Any]:
    check.__name__ = name
    return check


def _num(value: float) -> str:
    if isinstance(value, int) or (value.is_integer() and abs(value) < 1e16):
        return str(int(value))
    return f"{value:g}"


def _describe(low: float | None, high: float | None, above: float | None,
              unit: str) -> str:
    unit = f" {unit}" if unit else ""
    if above is not None:
        top = f" and <= {_num(high)}{unit}" if high is not None else ""
        return f"> {_num(above)}{unit}{top}"
    if low is not None and high is not None:
        return f"in {_num(low)}..{_num(high)}{unit}"
    return f">= {_num(low)}{unit}" if low is not None else f"<= {_num(high or 0)}{unit}"


def number(name: str, *, low: float | None = None, high: float | None = None,
           above: float | None = None, unit: str = "") -> Callable[[str], float]:
    """A finite float in ``low..high`` (or strictly more than ``above``, up to ``high``)."""
    want = _describe(low, high, above, unit)

    def check(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number {want}, got {text!r}")
        if (above is not None and not value > above) or (low is not None and value < low) \
                or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return value

    return _named(name, check)


def count(name: str, low: int, high: int, unit: str = "") -> Callable[[str], int]:
    """A whole number in ``low..high`` (decimal; ``0x`` hex too)."""
    want = _describe(low, high, None, unit)

    def check(text: str) -> int:
        value = _whole(text.strip())
        if value is None:
            raise argparse.ArgumentTypeError(f"must be a whole number {want}, got {text!r}")
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return value

    return _named(name, check)


def _whole(text: str) -> int | None:
    if len(text) > 40:
        return None
    for base in (0, 10):  # 0: 0x.. hex too; 10: a decimal with a leading zero
        try:
            return int(text, base)
        except ValueError:
            continue
    return None


def size(name: str, low: int, high: int) -> Callable[[str], int]:
    """Bytes: ``1000``, ``64k``, ``10M``, ``1G`` (powers of 1024), in ``low..high``."""
    want = f"in {size_text(low)}..{size_text(high)}" if low else f"at most {size_text(high)}"

    def check(text: str) -> int:
        try:
            value = parse_size(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {want} (e.g. 1000000, 64k, 10M, 1G), "
                                             f"got {text!r}")
        return value

    return _named(name, check)


def can_filter(text: str) -> dict[str, int]:
    """``ID:MASK`` (matches when id & mask == ID & mask) or ``ID~MASK`` (when it does
    not), hex, as python-can's ``--filter`` reads them."""
    for sep in (":", "~"):
        if sep in text:
            first, _, second = text.partition(sep)
            try:
                can_id, mask = int(first, 16), int(second, 16)
            except ValueError:
                break
            if not (0 <= can_id <= 0x1FFFFFFF and 0 <= mask <= 0x1FFFFFFF):
                raise argparse.ArgumentTypeError(f"{text!r}: ID and mask are 29-bit hex "
                                                 "numbers (0..1FFFFFFF)")
            if sep == "~":
                return {"can_id": can_id | 0x20000000, "can_mask": mask & 0x20000000}
            return {"can_id": can_id, "can_mask": mask}
    raise argparse.ArgumentTypeError(f"{text!r} is not a filter: ID:MASK or ID~MASK in hex "
                                     "(e.g. 100:7FC)")


can_filter.__name__ = "filter"

seconds = number("seconds", above=0.0, high=YEAR_S, unit="s")
"""A duration (``--seconds``, time-outs): more than 0, at most a year."""
rate_hz = number("rate", low=1e-3, high=1e6, unit="Hz")
seed = count("seed", 0, MAX_SEED)
bitrate = count("bitrate", 1_000, 20_000_000, "bit/s")
node_id = count("node-ID", 1, 127)
patches = count("patches", 1, 127)
buses = count("buses", 1, 127)
heartbeat_ms = count("milliseconds", 0, 0xFFFF, "ms")
port = count("port", 1, 65535)
fraction = number("fraction", low=0.0, high=0.999999)
percent = number("percent", above=0.0, high=100.0, unit="%")
rcvbuf = size("bytes", 0, 1 << 30)
rotate_size = size("bytes", 1 << 10, 1 << 40)


class _Filters(argparse.Action):
    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        setattr(namespace, self.dest, list(values))


def add_bus_arguments(parser: argparse.ArgumentParser, *, filter_arg: bool = False) -> None:
    """python-can's bus flags (``can.cli.add_bus_arguments``) with ranged ``--bitrate``
    and ``--data-bitrate`` and, with ``filter_arg``, a ``--filter`` that refuses what it
    cannot read in one line (python-can's raises a traceback)."""
    import can.cli

    can.cli.add_bus_arguments(parser)
    group = next(g for g in parser._action_groups if g.title == "bus arguments")
    for action in group._group_actions:
        if action.dest in ("bitrate", "data_bitrate"):
            action.type = bitrate
    if filter_arg:
        group.add_argument("--filter", dest="can_filters", nargs="+", type=can_filter,
                           action=_Filters, default=argparse.SUPPRESS,
                           metavar="{<can_id>:<can_mask>,<can_id>~<can_mask>}",
                           help="CAN filters (hex): ID:MASK passes a frame when its id & "
                                "MASK == ID & MASK, ID~MASK when it does not (e.g. 100:7FC)")


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr (no usage block):
    ``skin sim dataset: error: argument -n: ... (skin sim dataset --help)``, exit 2.
    Sub-command parsers are of the same class (argparse makes them of their parent's)."""

    def error(self, message: str) -> Any:
        text = " ".join(message.split())
        self.exit(2, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def output_file(text: str) -> str:
    """A path results may go to (:func:`skin.inputs.outputs.refusal`): a regular file or
    nothing yet, in a folder that exists. Checked again when it is written."""
    from skin.inputs.outputs import refusal

    why = refusal(text)
    if why is not None:
        raise argparse.ArgumentTypeError(f"cannot write {text!r}: {why}")
    return text


output_file.__name__ = "output file"
