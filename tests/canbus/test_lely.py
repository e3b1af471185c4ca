"""The shipped EDS files as lely's tools read them: ``dcfchk`` (no warning) and ``dcfgen``
(a master DCF whose RPDOs map every force PDO), run as outside checkers (dcf-tools is in
the ``test`` extra); and ``skin eds check`` agrees with ``dcfchk`` on broken files."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import canopen
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbus.tools.edscheck import check
from tests.support.rigs import children

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "eds"
LELY = ROOT / "examples" / "lely"
TOOLS = Path(sys.executable).parent


def _tool(name: str) -> str:
    found = shutil.which(name, path=str(TOOLS)) or shutil.which(name)
    if found is None:
        pytest.skip(f"lely's {name} is not installed (pip install dcf-tools, in the test extra)")
    return found


def _run(*cmd: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return children.run(cmd, cwd=cwd, timeout=120)


@pytest.mark.parametrize(("eds", "node_id"), [("skin-patch.eds", 1), ("skin-patch.eds", 127),
                                              ("skin-forces.eds", 65)])
def test_dcfchk_passes_the_shipped_eds_without_a_warning(eds: str, node_id: int) -> None:
    done = _run(_tool("dcfchk"), "-n", str(node_id), "-p", str(EDS / eds))
    assert done.returncode == 0, done.stderr
    assert "Warning" not in done.stderr and "warn" not in done.stderr.lower(), done.stderr
    assert "TPDO" in done.stdout  # -p printed the mapping lely read


def _remote_tpdos(eds: Path, node_id: int) -> list[tuple[int, list[int]]]:
    """(COB-ID, mapping entries) of every valid TPDO of an EDS for ``node_id``, as canopen
    reads the file."""
    od = canopen.import_od(str(eds), node_id)
    out = []
    for n in range(512):
        if 0x1800 + n not in od:
            break
        cob = int(od[0x1800 + n][1].default)
        mapping = od[0x1A00 + n]
        count = int(mapping[0].default)
        if not cob & 0x8000_0000 and count:
            out.append((cob & 0x7FF, [int(mapping[s].default) for s in range(1, count + 1)]))
    return out


def _master_rpdos(dcf: Path) -> dict[int, list[int]]:
    """COB-ID -> the remote TPDO mapping the master's RPDO of that COB-ID reads (0x5A00+n)."""
    master = configparser.RawConfigParser(strict=False)
    master.optionxform = str  # type: ignore[assignment,method-assign]
    master.read(dcf)

    def value(section: str, key: str = "DefaultValue") -> str:
        return master.get(section, "ParameterValue", fallback=None) or master.get(section, key)

    out: dict[int, list[int]] = {}
    for n in range(512):
        comm = f"{0x1400 + n:04X}sub1"
        if not master.has_section(comm):
            continue
        cob = int(value(comm), 0)
        remote = f"{0x5A00 + n:04X}Value"
        entries = dict(master.items(remote)) if master.has_section(remote) else {}
        count = int(entries.pop("NrOfEntries", "0"))
        out[cob & 0x7FF] = [int(entries[str(k)], 0) for k in range(1, count + 1)]
    return out


def _dcfgen(config: Path, out: Path) -> Path:
    done = _run(_tool("dcfgen"), "-r", "-d", str(out), str(config.name), cwd=config.parent)
    assert done.returncode == 0, done.stderr
    assert "Warning" not in done.stderr, done.stderr
    return out / "master.dcf"


def _forces_mapped(master: dict[int, list[int]], node_ids: list[int]) -> None:
    for node_id in node_ids:
        for cob, entries in _remote_tpdos(EDS / "skin-forces.eds", node_id):
            assert master.get(cob) == entries, f"force node {node_id} TPDO 0x{cob:03X}"


def test_dcfgen_builds_the_example_bus(tmp_path: Path) -> None:
    master = _master_rpdos(_dcfgen(LELY / "bus.yml", tmp_path))
    _forces_mapped(master, [65, 66])
    for node_id in (1, 2):  # the patches' resistance TPDOs too
        for cob, entries in _remote_tpdos(EDS / "skin-patch.eds", node_id):
            assert master[cob] == entries
    assert len(master) == 2 * 7 + 2 * 8  # the patches' 7 TPDOs, the force nodes' 7 and the contact


def _layout(patches: list[int], offset: int, with_patches: bool, sync_us: int) -> str:
    lines = ["master:", "  node_id: 127", f"  sync_period: {sync_us}", "  start_nodes: true"]
    for p in patches:
        if with_patches:
            lines += [f"patch_{p}:", f"  dcf: \"{EDS / 'skin-patch.eds'}\"", f"  node_id: {p}",
                      "  heartbeat_producer: 100"]
        lines += [f"forces_{p}:", f"  dcf: \"{EDS / 'skin-forces.eds'}\"",
                  f"  node_id: {p + offset}", "  boot: false"]
    return "\n".join(lines) + "\n"


@settings(max_examples=4, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(patches=st.lists(st.integers(1, 32), min_size=1, max_size=6, unique=True),
       offset=st.sampled_from([32, 64, 95]), with_patches=st.booleans(),
       sync_us=st.sampled_from([2000, 10000]))
def test_dcfgen_maps_every_force_pdo_of_other_bus_layouts(
        tmp_path: Path, patches: list[int], offset: int, with_patches: bool,
        sync_us: int) -> None:
    if with_patches and offset == 32 and any(p + 32 in patches for p in patches):
        return  # a node-ID twice: not a bus
    where = tmp_path / f"{'-'.join(map(str, patches))}-{offset}-{with_patches}"
    where.mkdir()
    config = where / "bus.yml"
    config.write_text(_layout(patches, offset, with_patches, sync_us))
    master = _master_rpdos(_dcfgen(config, where))
    _forces_mapped(master, [p + offset for p in patches])


def _dcfchk_warnings(path: Path) -> list[str]:
    done = _run(_tool("dcfchk"), "-n", "1", str(path))
    return [line for line in done.stderr.splitlines() if "Warning" in line]


def _broken(tmp_path: Path, old: str, new: str, name: str) -> Path:
    text = (EDS / "skin-patch.eds").read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(("old", "new"), [
    ("DataType=0x0007\nAccessType=ro\nLowLimit=100\nHighLimit=1000000000\nDefaultValue=50000",
     "DataType=0x0008\nAccessType=ro\nDefaultValue=0.05"),  # a REAL32 default
    ("HighLimit=1000000000\nDefaultValue=25000000",
     "HighLimit=1000000000\nDefaultValue=4294967295"),  # E beyond its HighLimit
    ("LSS_Supported=1", "LSS_Supported=1\nColour=blue"),  # not a CiA 306 key
    ("[1003]\nParameterName=Pre-defined error field\nObjectType=0x8",
     "[1003]\nParameterName=Pre-defined error field\nObjectType=0x8\nAccessType=rw"),
    ("DefaultValue=1000\nPDOMapping=0", "DefaultValue=70000\nPDOMapping=0"),  # > UNSIGNED16
    ("DefaultValue=1000\nPDOMapping=0", "DefaultValue=1e3\nPDOMapping=0"),  # not an integer
    ("[MandatoryObjects]\nSupportedObjects=3\n1=0x1000",
     "[MandatoryObjects]\nSupportedObjects=3\n1=0x1017"),  # not mandatory (and 0x1000 unlisted)
    ("Dummy0001=0", "Dummy0001=2"),
])
def test_skin_eds_check_refuses_what_dcfchk_warns_about(tmp_path: Path, old: str,
                                                       new: str) -> None:
    path = _broken(tmp_path, old, new, "broken.eds")
    assert _dcfchk_warnings(path) or _run(_tool("dcfchk"), str(path)).returncode != 0
    assert check(path), "skin eds check let through what lely's dcfchk refuses"


_LINES = (EDS / "skin-patch.eds").read_text().splitlines()


@settings(max_examples=60)
@given(st.lists(st.tuples(st.integers(0, len(_LINES) - 1),
                          st.one_of(st.text(max_size=12),
                                    st.sampled_from(["0x", "0012", "-0x10", "$NODEID+",
                                                     "$NODEID+0x80", "1e3", "0.5", "", "[",
                                                     "ObjectType=0x8", "SubNumber=200",
                                                     "DataType=0x0008", "AccessType=rw"]))),
                min_size=1, max_size=4))
def test_skin_eds_check_reads_any_broken_file_into_lines(edits: list[tuple[int, str]]) -> None:
    """Broken files are judged, never crash the checker: one line per problem."""
    lines = list(_LINES)
    for at, text in edits:
        key = lines[at].split("=", 1)[0] if "=" in lines[at] else ""
        lines[at] = f"{key}={text}" if key and "=" not in text else text
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "broken.eds"
        path.write_text("\n".join(lines) + "\n")
        problems = check(path)
    assert all(isinstance(p, str) and "\n" not in p for p in problems)
