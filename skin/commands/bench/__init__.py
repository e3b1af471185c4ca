"""``skin bench [decoders|cross|paper|sim|dataplane|server|publish|contact|realtime|robot]``:
decoders' speed against error and the paper's Table 1, decoders trained on one scene and tested on
others, the paper's figures, the simulator's speed, the CAN data plane against canopen's
PdoMap callbacks, the patch server against python-can's own send, hosts publishing on
Zenoh, or the contact summary against the simulator's truth."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

from skin.commands.common import argtypes


def add_subparser(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "bench", help="speed against error of every decoder; the paper's Table 1; cross-scene",
        description="decoders: fit every registered decoder on `paper` (the paper's noise-free "
                    "protocol) and `paper-noisy` (the noise study) with 1000 training and 100 "
                    "test samples and several seeds, time it, sweep lm-mlp's hidden nodes "
                    "5..14 (the paper's Table 1) on `paper`, `paper-noisy` and `indenter`, "
                    "and choose the hidden layer by the paper's method (--hidden auto). "
                    "cross: every decoder trained on one scene and tested on the others. "
                    "paper: the paper's Figures 8, 9 and 10 with its claims beside ours. "
                    "sim: the simulator's speed. dataplane: 16 patches' TPDOs absorbed, "
                    "decoded and republished as force TPDOs, against the same work through "
                    "canopen's PdoMap callbacks. server: N simulated patches served on "
                    "udp_multicast to a master in another process, the server's CPU per "
                    "frame against python-can's own send of the same frames in the same run, "
                    "SYNC to the last TPDO, patches per core. publish: H host processes "
                    "publishing on Zenoh and one reader, on loopback (docs/zenoh.md). "
                    "contact: each patch's contact summary (CoP, net force, slip onset) "
                    "against the simulator's truth on indenter, slide, grasp and stick-slip, "
                    "and its cost in the data plane. realtime: N patches and the host on "
                    "udp_multicast beside K CPU-bound processes, the host at normal priority "
                    "and with --realtime, against a bare python-can receiver (docs/host.md). "
                    "robot: the example robot's probe presses, contacts on its links against "
                    "the true ones (docs/robot.md).")
    parser.add_argument("target", nargs="?",
                        choices=("decoders", "cross", "paper", "sim", "dataplane", "server",
                                 "publish", "contact", "realtime", "robot"),
                        default="decoders")
    parser.add_argument("--quick", action="store_true",
                        help="one seed, smaller batches and sets (about a minute or less)")
    parser.add_argument("--goal-units", choices=("N", "scaled"), default="N",
                        help="where lm-mlp's and hybrid's goal MSE 1e-4 is measured: on the "
                             "forces in newtons (default; MATLAB's default performance "
                             "function) or on the mapminmax-scaled outputs")
    parser.add_argument("--json", type=argtypes.output_file, metavar="FILE",
                        help="write the figures as JSON")
    parser.add_argument("--random", type=argtypes.count("pairs", 0, 1000), default=0,
                        metavar="N", help="cross: N more scene pairs drawn at random "
                                          "(skin.benchmarks.pairs)")
    parser.add_argument("--png", type=argtypes.output_file, metavar="FILE.png",
                        help="paper: draw the paper's Figures 8, 9 and 10 as ours")
    parser.add_argument("--no-contact", action="store_true",
                        help="dataplane: the force nodes publish no contact summary")
    parser.add_argument("--plot", type=argtypes.output_file, metavar="FILE.png",
                        help="draw speed against error")
    from skin.commands.bench.server import add_arguments

    add_arguments(parser)
    from skin.commands.bench.publish import add_arguments as add_publish_arguments

    add_publish_arguments(parser)
    from skin.commands.bench.contact import add_arguments as add_contact_arguments

    add_contact_arguments(parser)
    from skin.commands.bench.realtime import add_arguments as add_realtime_arguments

    add_realtime_arguments(parser)
    parser.set_defaults(func=run)


def _write_json(path: str, data: dict[str, Any]) -> None:
    from skin.atomic import atomic_write

    with atomic_write(path) as handle:
        handle.write(json.dumps(data, indent=2).encode() + b"\n")


def print_dataplane(result: dict[str, Any]) -> None:
    from skin.commands.common.tables import show

    rows = []
    for label, key in (("data plane", "dataplane"), ("data plane, batch 1", "per_patch"),
                       ("canopen PdoMaps", "canopen")):
        ratio = result["canopen_s"] / result[f"{key}_s"]
        rows.append([label, f"{result[f'{key}_frames_in_per_s']:,.0f}",
                     f"{result[f'{key}_frames_out_per_s']:,.0f}",
                     f"{100 * result[f'{key}_cpu_share']:.0f} %", f"{ratio:.2f}x"])
    contact = "with" if result.get("contact", True) else "without"
    show(f"data plane: {result['patches']} patches ({result['mode']}), "
         f"{result['frames_in']:,} PDOs in, {result['frames_out']:,} out "
         f"({contact} the contact summary)",
         ["path", "frames in/s", "frames out/s", "CPU", "vs canopen"], rows,
         caption=f"{result['cycles']} SYNC cycles; best of {result['repeats']}; one thread; "
                 "python-can delivery excluded")
    print(f"identical force frames: {result['identical_output']}; all samples complete: "
                  f"{result['all_samples_complete']}")
    print(f"not included above: python-can virtual bus -> Notifier delivery alone "
                  f"{result['notifier_frames_per_s']:,.0f} frames/s; the whole path (virtual "
                  f"bus, Notifier, data plane thread) {result['pipeline_frames_per_s']:,.0f} "
                  f"frames/s, {result['pipeline_mean_batch']:.1f} samples per decode; its "
                  f"receive side (the Notifier's and the data plane's threads, the sender "
                  f"not counted) {result['pipeline_receive_frames_per_cpu_s']:,.0f} frames per "
                  f"CPU second, {result['pipeline_receive_vs_dataplane']:.2f}x the data plane's "
                  f"own per CPU second")


def run(args: argparse.Namespace) -> int:
    from skin.commands.common.blas import limit_blas_threads

    limit_blas_threads()
    if args.target == "publish":
        from skin.commands.bench.publish import run_publish

        return run_publish(args, _write_json)
    result = _RUNNERS[args.target](args)
    if args.json:
        _write_json(args.json, result)
    if args.target == "decoders":
        from skin.commands.bench.report import uncovered
        from skin.commands.eval import NO_RESULT

        return NO_RESULT if uncovered(result) else 0  # a figure over no taxel: named first
    return 0


def _sim(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.sim import run_benchmark

    figures = run_benchmark(quick=args.quick)
    for key, value in figures.items():
        print(f"{key:<40} {value:>16,.3f}")
    return dict(figures)


def _dataplane(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.dataplane import run_dataplane_benchmark

    cycles, repeats = (100, 2) if args.quick else (300, 5)
    figures = run_dataplane_benchmark(cycles=cycles, repeats=repeats,
                                      contact=not args.no_contact)
    print_dataplane(figures)
    return figures


def _server(args: argparse.Namespace) -> dict[str, Any]:
    from skin.commands.bench.server import print_server, run_server

    result = run_server(args)
    print_server(result)
    return result


def _contact(args: argparse.Namespace) -> dict[str, Any]:
    from skin.commands.bench.contact import print_contact, run_contact

    result = run_contact(args)
    print_contact(result)
    return result


def _realtime(args: argparse.Namespace) -> dict[str, Any]:
    from skin.commands.bench.realtime import run_realtime

    return run_realtime(args)


def _robot(args: argparse.Namespace) -> dict[str, Any]:
    from skin.commands.bench.robot import run_robot  # docs/robot.md

    return run_robot(args)


def _cross(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.runs import mlp_params, run_cross
    from skin.commands.bench.cross import print_cross

    result = run_cross(args.quick, mlp_params(args.goal_units), args.random)
    print_cross(result)
    return result


def _paper(args: argparse.Namespace) -> dict[str, Any]:
    from skin.commands.bench.paper_view import run_command

    result: dict[str, Any] = run_command(args.quick, args.goal_units, args.json, args.png)
    return result


def _decoders(args: argparse.Namespace) -> dict[str, Any]:
    from skin.benchmarks.runs import SCENES, TABLE1_SCENES, run_decoders
    from skin.commands.bench.report import Stages, check_plot, plot, print_decoders

    if args.plot:
        check_plot(args.plot)  # before minutes of work, not after
    stages = Stages(len(SCENES) + len(TABLE1_SCENES) + 3)
    try:
        result = run_decoders(args.quick, args.goal_units, stages)
    finally:
        stages.close()
    print_decoders(result)
    if args.plot:
        plot(result, args.plot)
    return result


_RUNNERS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "sim": _sim, "dataplane": _dataplane, "server": _server, "contact": _contact,
    "cross": _cross, "paper": _paper, "decoders": _decoders, "realtime": _realtime,
    "robot": _robot,
}
