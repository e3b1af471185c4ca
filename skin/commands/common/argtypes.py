"""argparse types with ranges: every numeric option of every command uses one.

A value outside its range (``inf``, ``nan``, a negative count, an absurd size) is refused
by argparse, before the command does any work, in one line (``skin demo: error: argument
--seconds: ...``; exit status 2). Each factory returns a callable argparse uses as
``type=``; its name is what argparse's own messages call the value.

The python-can bus flags get theirs through :func:`add_bus_arguments` (its ``--bitrate``
and ``--data-bitrate``, and a ``--filter`` that says which filter it cannot read).
The checks are :mod:`skin.inputs.fields`', the ones every value of a file goes through
(:func:`checked` hands the problem they name to argparse): ``--node 200`` and ``node_id =
200`` are refused alike.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any, TypeVar

from skin.errors import ConfigError
from skin.inputs import fields
from skin.inputs.budget import parse_size, size_text

T = TypeVar("T")

YEAR_S = 365 * 24 * 3600
MAX_SEED = 2**63 - 1


def _named(name: str, check: Callable[[str], Any]) -> Callable[[str], Any]:
    check.__name__ = name
    return check


def checked(text: str, check: Callable[..., T], value: Any, *args: Any, **kwargs: Any) -> T:
    """``check(value, *args, **kwargs)``, one of :mod:`skin.inputs.fields`' checks of
    ``value`` read from ``text``; what it refuses is argparse's error, naming ``text``."""
    try:
        return check(value, *args, **kwargs)
    except fields.FieldError as err:
        raise argparse.ArgumentTypeError(f"must be {err.want}, got {text!r}") from None
    except ConfigError as err:
        raise argparse.ArgumentTypeError(err.problem) from None


def number(name: str, *, low: float | None = None, high: float | None = None,
           above: float | None = None, unit: str = "") -> Callable[[str], float]:
    """A finite float in ``low..high`` (or strictly more than ``above``, up to ``high``)."""

    def check(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        return checked(text, fields.number, value, name, low, high, above=above, unit=unit)

    return _named(name, check)


def count(name: str, low: int, high: int, unit: str = "") -> Callable[[str], int]:
    """A whole number in ``low..high`` (decimal; ``0x`` hex too)."""

    def check(text: str) -> int:
        value = _whole(text.strip())
        if value is None:
            raise argparse.ArgumentTypeError(f"must be a whole number "
                                             f"{fields.bounds(low, high, unit=unit)}, got "
                                             f"{text!r}")
        return checked(text, fields.integer, value, name, low, high, unit=unit)

    return _named(name, check)


def whole(name: str, check: Callable[[Any, str], int], want: str) -> Callable[[str], int]:
    """A whole number (decimal; ``0x`` hex too) that ``check`` takes, a check of
    :mod:`skin.inputs.fields` (:func:`~skin.inputs.fields.node_id`: ``want`` is
    :data:`~skin.inputs.fields.NODE_ID`)."""

    def parse(text: str) -> int:
        value = _whole(text.strip())
        if value is None:
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return checked(text, check, value, name)

    return _named(name, parse)


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
rate_hz = number("rate", low=1e-3, high=1_000_000, unit="Hz")
seed = count("seed", 0, MAX_SEED)
bitrate = count("bitrate", 1_000, 20_000_000, "bit/s")
node_id = whole("node-ID", fields.node_id, fields.NODE_ID)
"""A CANopen node-ID, 1..127."""
serial = whole("serial number", fields.serial_number, fields.SERIAL_NUMBER)
"""A serial number of object 0x1018 sub 4, 0..0xFFFFFFFF."""
patches = count("patches", 1, len(fields.NODE_IDS))
"""Patches, each at a node-ID of its own."""
buses = count("buses", 1, len(fields.NODE_IDS))
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
