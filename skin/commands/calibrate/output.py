"""What ``skin calibrate`` writes besides the model: the report as JSON and as the model
file's ``meta.calibration``, the host-config snippet, and the rest values sent to the
patch by SDO (``--write-node``). Imports of canbus and decoder stay inside the functions.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

NOMINAL = 0x2002
"""The patch's nominal (rest) resistances R0, 27 UNSIGNED32 in mOhm (eds/skin-patch.eds)."""


def plain(value: Any) -> Any:
    """JSON-able: arrays to lists, NaN and infinity to None."""
    import numpy as np

    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: str | os.PathLike[str], document: dict[str, Any]) -> None:
    from skin.atomic import atomic_write

    with atomic_write(path) as handle:
        handle.write(json.dumps(plain(document), indent=2, allow_nan=False).encode() + b"\n")


def model_meta(report: dict[str, Any], *, node_id: int, dataset: str) -> dict[str, Any]:
    """``meta.calibration`` of the model file: what model files can hold (scalars, strings,
    finite arrays, maps three deep), so lists become arrays and undefined figures go."""
    import numpy as np

    def arr(values: Any) -> Any:
        a = np.asarray(values, dtype=np.float64)
        return np.where(np.isfinite(a), a, 0.0)

    candidates = report["candidates"]
    meta: dict[str, Any] = {
        "decoder": report["decoder"], "candidate": report["candidate"],
        "hidden": report["hidden"],
        "heldout_floored_pct": float(report["heldout_floored_pct"]),
        "heldout_ave_rel_err_pct": _finite(report["heldout_ave_rel_err_pct"]),
        "rmse_N": float(report["rmse_N"]),
        "rmse_axis_N": arr(list(report["rmse_axis_N"].values())),
        "axes": " ".join(report["rmse_axis_N"]),
        "per_taxel_floored_pct": arr(report["per_taxel_floored_pct"]),
        "per_taxel_floored_count": np.asarray(report["per_taxel_floored_count"], np.int64),
        "per_taxel_rmse_N": arr(report["per_taxel_rmse_N"]),
        "flagged_pct": float(report["flagged_pct"]),
        "folds": int(report["folds"]), "samples": int(report["samples"]),
        "mode": report["mode"], "node_id": node_id, "dataset": dataset,
        "speed": {k: _finite(v) for k, v in report["speed"].items()},
        "tare": {"rest_ohm": None if report["tare"]["rest_ohm"] is None
                 else np.asarray(report["tare"]["rest_ohm"], np.float64),
                 "samples": int(report["tare"]["samples"]),
                 "rest_N": float(report["tare"]["rest_N"])},
        "domain": {k: (np.asarray(v, np.float64) if isinstance(v, np.ndarray) else v)
                   for k, v in report["domain"].items()},
        "candidates": {
            "names": " ".join(c["decoder"] for c in candidates),
            "heldout_floored_pct": arr([_nan(c["heldout_floored_pct"]) for c in candidates]),
            "flagged_pct": arr([c["flagged_pct"] for c in candidates]),
            "latency_us": arr([_nan(c["latency_us"]) for c in candidates]),
            "fit_s": arr([c["fit_s"] for c in candidates]),
            "eligible": np.array([c["eligible"] for c in candidates], dtype=bool)},
    }
    return meta


def _finite(value: Any) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _nan(value: Any) -> float:
    return math.nan if value is None else float(value)


def save_model(decoder: Any, path: str | os.PathLike[str], meta: dict[str, Any]) -> None:
    """The fitted decoder's model file with ``meta.calibration`` added, written atomically
    (through a temporary file in the target's folder)."""
    import tempfile

    from decoder.modelfile import read_model, write_model

    folder = Path(path).parent if str(Path(path).parent) else Path(".")
    with tempfile.TemporaryDirectory(dir=folder, prefix=".calibrate.") as scratch:
        plain_path = Path(scratch) / "model.msgpack"
        decoder.save(plain_path)
        content = read_model(plain_path)
    write_model(path, content.name, content.params, content.state,
                {**content.meta, "calibration": meta})


def snippet(node_id: int, mode: str, model: str, rest_ohm: Any, snippet_path: str | None,
            nominal: Any) -> str:
    """A host config's ``[[patches]]`` table for the calibrated patch: its model and, for a
    listen-only host, its rest as ``r0_ohm`` (27 values; pillars a z-only patch does not
    read keep their nominal R0)."""
    import numpy as np

    where = Path(snippet_path).parent if snippet_path else Path(".")
    try:
        relative = os.path.relpath(model, where)
    except ValueError:  # another drive
        relative = os.path.abspath(model)
    lines = ["# skin calibrate: add to the host config (docs/calibrate.md)", "[[patches]]",
             f"node_id = {node_id}", f'mode = "{mode}"', f"model = {json.dumps(relative)}"]
    if rest_ohm is not None:
        table = np.array(np.broadcast_to(nominal, (9, 3)), dtype=np.float64)
        rest = np.asarray(rest_ohm, dtype=np.float64)
        table[:, : rest.shape[1]] = rest
        values = ", ".join(repr(float(v)) for v in table.ravel().tolist())
        lines += ["# the patch's rest (tare): a listen-only host takes it from here; an active",
                  "# host reads the patch's 0x2002 (skin calibrate --write-node)",
                  f"r0_ohm = [{values}]"]
    return "\n".join(lines) + "\n"


def write_rest_to_node(args: Any, node_id: int, rest_ohm: Any) -> int:
    """SDO downloads of the rest values to the patch's 0x2002 (sub taxel·3 + pillar + 1),
    then with ``args.store`` 0x1010 sub 4 "save"; returns how many were written. BusError
    names the sub-index a patch refused."""
    import canopen
    import numpy as np
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    from canbus.od import load_od
    from canbus.patch_constants import encode_si
    from skin.commands.common.busopen import open_command_bus
    from skin.errors import BusError, ConfigError

    rest = np.asarray(rest_ohm, dtype=np.float64)
    payloads: dict[int, bytes] = {}  # every value checked before the first is written
    for taxel in range(rest.shape[0]):
        for pillar in range(rest.shape[1]):
            sub = 3 * taxel + pillar + 1
            try:
                payloads[sub] = encode_si(NOMINAL, sub, float(rest[taxel, pillar]))
            except ConfigError as err:
                raise ConfigError(f"rest 0x2002:{sub:02X}", err.problem) from err
    bus, described = open_command_bus(args, command="skin calibrate --write-node", sends=True)
    args.described = described
    written = 0
    with bus:
        network = canopen.Network(bus)
        network.connect()
        try:
            node = network.add_node(canopen.RemoteNode(node_id, load_od("skin-patch", node_id)))
            node.sdo.RESPONSE_TIMEOUT = args.sdo_timeout
            for sub, value in payloads.items():
                try:
                    node.sdo.download(NOMINAL, sub, value)
                except SdoAbortedError as err:
                    ohm = rest[(sub - 1) // 3, (sub - 1) % 3]
                    raise BusError(f"patch {node_id} refused R0 0x2002:{sub:02X} = "
                                   f"{ohm:g} ohm: abort 0x{err.code:08X} ({err})") from err
                except SdoCommunicationError as err:
                    raise BusError(f"patch {node_id} did not answer on {described}: "
                                   f"{err}") from err
                written += 1
            if getattr(args, "store", False):
                _save_manufacturer_parameters(node, node_id)
        finally:
            network.disconnect()
    return written


def _save_manufacturer_parameters(node: Any, node_id: int) -> None:
    """0x1010 sub 4 "save": the patch keeps its manufacturer parameters (R0) across
    power-off (CiA 301's signature, 0x65766173)."""
    from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

    from skin.errors import BusError

    try:
        node.sdo.download(0x1010, 4, b"save")
    except (SdoAbortedError, SdoCommunicationError) as err:
        raise BusError(f"patch {node_id} did not save its parameters (0x1010:04): {err}") \
            from err
