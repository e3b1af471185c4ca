"""``skin dataset from-recording REC --reference F.csv -o D.npz``: a calibration dataset
from a bus recording and reference forces (docs/calibrate.md).

The patches' resistances are read from the recording by the mapping it shows (the SDO
writes its master made; the EDS default otherwise; ``--mapping`` overrides), assembled
one sample per SYNC by the host's own data plane, joined to the reference by SYNC counter
or by time, and written in the format ``skin sim dataset`` writes. Incomplete samples,
faulty taxels and samples that cannot be joined are counted and left out.
"""

from __future__ import annotations

import argparse
from typing import Any

from skin.commands.common import argtypes

_SOURCES = {"sdo": "the SDO writes", "eds": "the EDS default", "option": "--mapping"}


def _from_recording(args: argparse.Namespace) -> int:
    from canbus.offline.dataset import JoinChoice, dataset_from_recording
    from canbus.tools.recording import recording_reader
    from skin.commands.calibrate.output import write_json
    from skin.dataset import write_dataset
    from skin.errors import ConfigError

    recording_reader(args.recording, field="REC")
    if not str(args.output).lower().endswith(".npz"):
        raise ConfigError("-o", f"a dataset is an .npz file, got {args.output!r}")
    how = JoinChoice(args.join, args.tolerance_ms, args.clock_offset_ms)
    nodes = tuple(args.node) if args.node else None
    from skin.commands.decode_report import quiet_host

    with quiet_host():
        made = dataset_from_recording(args.recording, args.reference, nodes=nodes,
                                      mapping=args.mapping, how=how,
                                      sync_window_ms=args.sync_window_ms,
                                      heartbeat_ms=args.heartbeat_ms,
                                      answer_order=args.answer_order)
    report = made.report
    _print(args, report)
    if args.json:
        write_json(args.json, {"recording": args.recording, "reference": args.reference,
                               "output": args.output, **report})
    ds = made.dataset
    if ds.resistance_ohm.shape[0] == 0:
        raise ConfigError("--reference", f"no sample of {args.recording} could be joined to "
                          f"{args.reference} (counts above): nothing written")
    write_dataset(args.output, ds)
    s, p, _, pillars = ds.resistance_ohm.shape
    print(f"wrote {args.output}: {s} samples x {p} patch{'es' if p > 1 else ''} x 9 taxels x "
          f"{pillars} pillar{'s' if pillars > 1 else ''}")
    return 0


def _print(args: argparse.Namespace, report: dict[str, Any]) -> None:
    join = report["join"]
    how = "SYNC counter" if join["by"] == "sync" else "time"
    if join["clock_offset_ms"] is None:
        offset = "none: no sample to join"
    elif join["clock_offset_estimated"] and join["correlation"] is not None:
        offset = f"{join['clock_offset_ms']:.3f} ms, estimated: load/readings correlation " \
            f"{join['correlation']:.3f}"
    else:
        offset = f"{join['clock_offset_ms']:.3f} ms, " + \
            ("from the SYNC counters" if join["clock_offset_estimated"] else "given")
    print(f"read {args.recording}: {report['recording_frames']} frames, SYNC every "
          f"{report['sync_period_ms']:.3f} ms (window {report['sync_window_ms']:.3f} ms, "
          f"heartbeat {report['heartbeat_ms']} ms)")
    print(f"joined {args.reference} ({report['reference_rows']} rows, {report['reference_form']}"
          f" form) by {how} within {join['tolerance_ms']:.3f} ms; clock offset {offset}")
    for node, p in report["patches"].items():
        rec, ref = p["recording"], p["reference"]
        mapping = report["mapping"][node]
        faulty = ", ".join(f"{k} {v}" for k, v in rec["faulty_taxels"].items()) or "none"
        source = _SOURCES[mapping["from"]]
        print(f"patch {node} ({mapping['mapping']} mapping, from {source}): "
              f"{rec['samples']} samples, {rec['complete']} complete, {rec['incomplete']} "
              f"incomplete, {rec['unanswered']} unanswered, {rec['with_faulty_taxels']} with "
              f"faulty taxels (taxels: {faulty})")
        print(f"  reference: {ref['samples']} samples ({ref['incomplete']} incomplete, left "
              f"out); joined {p['joined']}; left out: {p['joined_but_incomplete']} incomplete, "
              f"{p['joined_but_unanswered']} unanswered, {p['joined_but_faulty']} faulty, "
              f"{p['left_out_other_patch']} for another patch; unjoined: "
              f"{p['unjoined_reference']} reference, {p['unjoined_recording']} recorded; "
              f"written {p['written']}")


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser("dataset", help="calibration datasets from bus recordings")
    group = parser.add_subparsers(title="dataset commands", metavar="ACTION", required=True)
    make = group.add_parser(
        "from-recording", help="a dataset from a recording and reference forces",
        description="Read each patch's resistances from a recording (.log, .asc, .blf, "
                    ".pcap, .pcapng) as the host's data plane assembles them, one sample "
                    "per SYNC, join them to reference forces (CSV or .npz: docs/calibrate.md) "
                    "by SYNC counter or by time, and write a dataset in the format skin sim "
                    "dataset writes. Incomplete samples, faulty taxels and samples that "
                    "cannot be joined are counted and left out.")
    make.add_argument("recording", metavar="REC", help="the bus recording")
    make.add_argument("--reference", required=True, metavar="F.csv|F.npz",
                      help="reference forces (skin sim run --truth writes them)")
    make.add_argument("-o", "--output", type=argtypes.output_file, required=True, metavar="D.npz")
    make.add_argument("--node", type=argtypes.node_id, action="append", metavar="N",
                      help="a patch to read (repeat; default: every patch of the reference)")
    make.add_argument("--mapping", choices=("z", "xyz", "fd-z", "fd-xyz"),
                      help="the patches' TPDO mapping (default: what the recording's SDO "
                           "transfers show, else the EDS default)")
    make.add_argument("--join", choices=("sync", "time"),
                      help="join by SYNC counter or by time (default: sync when the "
                           "reference and the SYNCs carry counters)")
    make.add_argument("--tolerance-ms",
                      type=argtypes.number("milliseconds", above=0.0, high=10**9, unit="ms"),
                      metavar="MS",
                      help="how far apart a joined pair may be on one clock (default: "
                           "40 %% of the SYNC period by time, 60 SYNC periods by counter)")
    make.add_argument("--clock-offset-ms",
                      type=argtypes.number("milliseconds", low=-10**13, high=10**13, unit="ms"),
                      metavar="MS",
                      help="reference time + this = recording time (default: estimated)")
    make.add_argument("--sync-window-ms",
                      type=argtypes.number("milliseconds", above=0.0, high=60_000.0, unit="ms"),
                      metavar="MS",
                      help="the SYNC window the recording's master used (default 80 %% of "
                           "the SYNC period, the host's default)")
    make.add_argument("--answer-order", choices=("cob-id", "tpdo"), default="cob-id",
                      help="how the patches order one answer's TPDOs (default cob-id; "
                           "docs/host.md)")
    make.add_argument("--heartbeat-ms", type=argtypes.count("milliseconds", 1, 0xFFFF, "ms"),
                      metavar="MS",
                      help="the patches' heartbeat period (default: what their master "
                           "wrote, else what they beat at)")
    make.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                      help="write the counts as JSON")
    make.set_defaults(func=_from_recording)
