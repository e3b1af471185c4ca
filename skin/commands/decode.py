"""``skin decode REC --config host.toml -o forces.csv|.npz``: a recording's forces, offline.

The recording (.log, .asc, .blf, .pcap, .pcapng, .mcap) goes through the listen-only host on its
own clock (:mod:`canbus.offline.decode`): the forces are what a listen-only host publishes
for it, the same every time, with no bus; what it says of each patch (samples, stretches
without an answer, invalid taxels) is in seconds of the recording
(:mod:`skin.commands.decode_report`), never a live host's "lost" or "in the last N s".
Output, written atomically:

- ``.csv``: one row per taxel of every sample: ``cycle, sync_counter, time_s, patch,
  force_node, taxel, fx_N, fy_N, fz_N, valid, reason, complete`` (``reason`` by name);
- ``.npz``: arrays ``cycle, sync_counter, time_s, patch, force_node, complete`` (samples,)
  and ``force_N`` (samples, 9, 3), ``valid``, ``reason`` (samples, 9), and ``meta`` (JSON);
  and each sample's contact summary (docs/contact.md): ``contact_force_N``,
  ``contact_torque_Nm`` (samples, 3), ``cop_m``, ``cop_placed_m`` (samples, 2; 0 where
  ``cop_defined`` is False), ``cop_defined``, ``taxels_in_contact``, ``valid_taxels``,
  ``tangential_ratio``, ``contact_state`` (the state byte, as on the bus) (samples,),
  ``contact_taxels``, ``slip_taxels`` (samples, 9);
- ``.mcap``: the recording's frames and every sample (taxels, wrench, CoP, contact
  state) in ROS 2 messages (docs/mcap.md), as ``skin run --record F.mcap`` writes them;
- ``--contact F.csv``: one row per sample: ``cycle, sync_counter, time_s, patch,
  force_node``, the net force, torque, CoP in both frames (empty where not defined), the
  counts, the ratio, and the state (``in_contact, onset, release, near_slip, slipping,
  slip_onset, partial, unknown`` as 0 or 1).
"""

from __future__ import annotations

import argparse
import io
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skin.commands.common import argtypes

if TYPE_CHECKING:
    from canbus.master.dataplane import ForceFrame

FORMATS = (".csv", ".npz", ".mcap")


def _decode(args: argparse.Namespace) -> int:
    from canbus.master.hostconfig import load_host_config
    from canbus.offline.decode import decode_recording
    from canbus.tools.recording import recording_reader
    from skin.atomic import atomic_write
    from skin.commands.decode_report import first_frame_time, lines, quiet_host, report, to_json
    from skin.errors import ConfigError

    recording_reader(args.recording, field="REC")
    suffix = Path(args.output).suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError("-o", f"unknown output format {suffix or '(no suffix)'!r}; use "
                          f"{' or '.join(FORMATS)}")
    if args.contact and Path(args.contact).suffix.lower() != ".csv":
        raise ConfigError("--contact", f"the contact table is a .csv file, got {args.contact!r}")
    if suffix == ".mcap":
        from canbus.tools.mcap_messages import require_mcap

        require_mcap("-o")
    config = load_host_config(args.config)
    with quiet_host():
        frames = decode_recording(args.recording, config)
    contact = _contact_csv(frames) if args.contact else None
    if suffix == ".mcap":
        from canbus.offline.mcap import write_decoded

        write_decoded(args.output, args.recording, frames, config)
    else:
        data = _csv(frames) if suffix == ".csv" else _npz(frames, args, config.source)
        with atomic_write(args.output) as handle:
            handle.write(data)
    if contact is not None:
        with atomic_write(args.contact) as handle:
            handle.write(contact)
    complete = sum(f.complete for f in frames)
    patches = sorted({f.patch for f in frames})
    print(f"decoded {len(frames)} samples ({complete} complete) of patches "
          f"{', '.join(map(str, patches)) or 'none'} from {args.recording} -> {args.output}")
    reports = report(frames, first_frame_time(args.recording))
    for line in lines(reports):
        print(line)
    if args.json:
        summary = {"recording": args.recording, "output": args.output, "samples": len(frames),
                   "complete_samples": complete,
                   "patches": {str(p): sum(f.patch == p for f in frames) for p in patches},
                   "by_patch": to_json(reports)}
        with atomic_write(args.json) as handle:
            handle.write(json.dumps(summary, indent=2).encode() + b"\n")
    return 0


def _csv(frames: list[ForceFrame]) -> bytes:
    from decoder.reasons import reason_name

    out = io.StringIO()
    out.write("cycle,sync_counter,time_s,patch,force_node,taxel,fx_N,fy_N,fz_N,valid,reason,"
              "complete\n")
    for f in frames:
        for taxel in range(len(f.valid)):
            fx, fy, fz = (repr(float(v)) for v in f.force_N[taxel])
            out.write(f"{f.cycle},{f.sync_counter},{f.timestamp!r},{f.patch},{f.force_node},"
                      f"{taxel},{fx},{fy},{fz},{int(f.valid[taxel])},"
                      f"{reason_name(int(f.reason[taxel]))},{int(f.complete)}\n")
    return out.getvalue().encode()


def _npz(frames: list[ForceFrame], args: argparse.Namespace, config: str) -> bytes:
    import numpy as np

    arrays: dict[str, Any] = {
        "cycle": np.array([f.cycle for f in frames], dtype=np.int64),
        "sync_counter": np.array([f.sync_counter for f in frames], dtype=np.uint8),
        "time_s": np.array([f.timestamp for f in frames], dtype=np.float64),
        "patch": np.array([f.patch for f in frames], dtype=np.uint8),
        "force_node": np.array([f.force_node for f in frames], dtype=np.uint8),
        "complete": np.array([f.complete for f in frames], dtype=bool),
        "force_N": np.array([f.force_N for f in frames], dtype=np.float64).reshape(-1, 9, 3),
        "valid": np.array([f.valid for f in frames], dtype=bool).reshape(-1, 9),
        "reason": np.array([f.reason for f in frames], dtype=np.uint8).reshape(-1, 9),
        "meta": np.array(json.dumps({"recording": args.recording, "config": config})),
        **_contact_arrays(frames),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _contact_arrays(frames: list[ForceFrame]) -> dict[str, Any]:
    """The samples' contact summaries as arrays (none when the config turned them off)."""
    import numpy as np

    from skin.contact_state import ContactSummary

    rows = [f.contact for f in frames]
    if not rows or any(c is None for c in rows):
        return {}
    summaries: list[ContactSummary] = [c for c in rows if c is not None]
    state = [_state_byte(c) for c in summaries]

    def stack(name: str, dtype: Any) -> Any:
        return np.array([getattr(c, name) for c in summaries], dtype=dtype)

    return {"contact_force_N": stack("force_N", np.float64),
            "contact_torque_Nm": stack("torque_Nm", np.float64),
            "cop_m": stack("cop_m", np.float64), "cop_placed_m": stack("cop_placed_m", np.float64),
            "cop_defined": stack("cop_defined", bool),
            "taxels_in_contact": stack("taxels_in_contact", np.uint8),
            "valid_taxels": stack("valid_taxels", np.uint8),
            "tangential_ratio": stack("tangential_ratio", np.float64),
            "contact_state": np.array(state, dtype=np.uint8),
            "contact_taxels": stack("contact_taxels", bool),
            "slip_taxels": stack("taxel_slip", bool)}


STATE_FIELDS = ("in_contact", "onset", "release", "near_slip", "slipping", "slip_onset",
                "partial", "unknown")
"""The state byte's bits, 0 up (0x2008 sub-index 11)."""


def _state_byte(contact: Any) -> int:
    return sum(1 << k for k, name in enumerate(STATE_FIELDS) if getattr(contact, name))


def _contact_csv(frames: list[ForceFrame]) -> bytes:
    out = io.StringIO()
    out.write("cycle,sync_counter,time_s,patch,force_node,fx_N,fy_N,fz_N,tx_Nm,ty_Nm,tz_Nm,"
              "cop_x_m,cop_y_m,cop_placed_x_m,cop_placed_y_m,taxels_in_contact,valid_taxels,"
              f"tangential_ratio,{','.join(STATE_FIELDS)}\n")
    for f in frames:
        c = f.contact
        if c is None:
            continue
        numbers = [*c.force_N.tolist(), *c.torque_Nm.tolist()]
        cop = [*c.cop_m.tolist(), *c.cop_placed_m.tolist()] if c.cop_defined else [""] * 4
        flags = ",".join(str(int(getattr(c, name))) for name in STATE_FIELDS)
        out.write(f"{f.cycle},{f.sync_counter},{f.timestamp!r},{f.patch},{f.force_node},"
                  f"{','.join(map(repr, numbers))},{','.join(map(str, cop))},"
                  f"{c.taxels_in_contact},{c.valid_taxels},{c.tangential_ratio!r},{flags}\n")
    return out.getvalue().encode()


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "decode", help="a recording's forces, offline (as a listen-only host publishes them)",
        description="Decode the patches' PDOs in a recording (.log, .asc, .blf, .pcap, "
                    ".pcapng, .mcap) into forces with the host config's decoders, on the "
                    "recording's own clock: what a listen-only host publishes for it, "
                    "the same every time, without a bus.")
    parser.add_argument("recording", metavar="REC", help="the recording")
    parser.add_argument("--config", required=True, metavar="CONFIG",
                        help="the host config (patches, modes, decoders, SYNC window)")
    parser.add_argument("-o", "--output", type=argtypes.output_file, required=True,
                        metavar="F.csv|F.npz|F.mcap",
                        help="the forces: a table (.csv), arrays (.npz), or an MCAP file of "
                             "the recording's frames and the samples in ROS 2 messages "
                             "(.mcap, docs/mcap.md)")
    parser.add_argument("--contact", type=argtypes.output_file, metavar="F.csv",
                        help="also write each sample's contact summary, one row per sample")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write a summary as JSON")
    parser.set_defaults(func=_decode)
