"""EDS files damaged on purpose: ``skin eds check`` names each problem on one line,
``skin sniff --eds`` (and every EDS canskin loads) refuses the file in one line; counts are
checked before anything loops over them."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from canbus.od import load_od
from skin.errors import ConfigError
from tests.inputs.conftest import examples
from tests.inputs.hostile import fingerprint, message_of, mutate_bytes, refused, run

PATCH = Path(__file__).resolve().parents[2] / "eds" / "skin-patch.eds"
KEYS = ("SubNumber", "ObjectType", "DataType", "AccessType", "DefaultValue", "LowLimit",
        "HighLimit", "PDOMapping", "SupportedObjects", "CompactSubObj", "ParameterName")
VALUES = ("x", "", "0x", "-1", "0xFFFFFFFFFFFFFFFFFFFF", "$NODEID+zz", "$NODEID", "1e3",
          "nan", "0x7FFFFFFF", "\xff", "=", "0x1A", "+", "-0x80", "inf", "0x99", "256")


def _check(path: Path) -> None:
    before = fingerprint(path.parent)
    result = run("eds", "check", path)
    assert "Traceback" not in result.err and "unexpected" not in result.err, result.err
    if result.code:
        assert result.lines and all(line.startswith(f"{path}: ") for line in result.lines)
    message = message_of(lambda: load_od(path, 5), ConfigError)
    assert message is None or ("\n" not in message and message.startswith(str(path))), message
    assert fingerprint(path.parent) == before


@examples(30)
@given(data=st.data())
def test_an_eds_damaged_in_its_values(tmp_path_factory: pytest.TempPathFactory,
                                      data: st.DataObject) -> None:
    lines = PATCH.read_text().splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.integers(0, len(lines) - 1))
        kind = data.draw(st.sampled_from(("value", "key", "delete", "duplicate", "insert")))
        if kind == "value" and "=" in lines[at]:
            lines[at] = lines[at].split("=")[0] + "=" + data.draw(st.sampled_from(VALUES))
        elif kind == "key" and "=" in lines[at]:
            lines[at] = data.draw(st.sampled_from(KEYS)) + "=" + data.draw(
                st.sampled_from(VALUES))
        elif kind == "delete":
            del lines[at]
        elif kind == "duplicate":
            lines.insert(at, lines[at])
        else:
            lines.insert(at, data.draw(st.sampled_from((
                "[1234sub5]", "garbage", "[DummyUsage]", "[2000Name]", "NrOfEntries=zz",
                "[1FFFsub1]", "[2000sub1FF]", "[Comments]", "Lines=70000"))))
    path = tmp_path_factory.mktemp("eds") / "patch.eds"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogateescape")
    _check(path)


@examples(15)
@given(data=st.data())
def test_an_eds_damaged_in_its_bytes(tmp_path_factory: pytest.TempPathFactory,
                                     data: st.DataObject) -> None:
    path = tmp_path_factory.mktemp("eds") / "patch.eds"
    path.write_bytes(mutate_bytes(PATCH.read_bytes(), data.draw))
    _check(path)


@pytest.mark.parametrize(("old", "new", "problem"), [
    ("SubNumber=65", "SubNumber=x", "[1A00] SubNumber 'x'"),
    ("SupportedObjects=3", "SupportedObjects=three", "SupportedObjects 'three'"),
    ("1=0x1000", "1=0xZZ", "1=0xZZ is not an object index"),
    ("$NODEID+0x180", "$NODEID+zz", "'$NODEID+zz' is not an integer"),
    ("DefaultValue=4\nPDOMapping=0\nLowLimit=0\nHighLimit=64",
     "DefaultValue=0x7FFFFFFF\nPDOMapping=0\nLowLimit=0\nHighLimit=64", "out of range 0..255"),
    ("LowLimit=0\nHighLimit=64", "LowLimit=60\nHighLimit=4", "LowLimit 60 is above HighLimit 4"),
    ("DataType=0x0006\nAccessType=rw\nDefaultValue=1000",
     "DataType=0x0006\nAccessType=rw\nDefaultValue=0xFFFFFFFFFFFFFFFFFFFF", "out of range"),
    ("[FileInfo]", "[FileInfo]\nthis line is no key", "line 2: not a key=value line"),
])
def test_the_issues_eds_examples(tmp_path: Path, old: str, new: str, problem: str) -> None:
    text = PATCH.read_text()
    assert old in text
    path = tmp_path / "bad.eds"
    path.write_text(text.replace(old, new, 1))
    check = run("eds", "check", path)
    assert check.code == 1 and check.lines and problem in check.lines[0], check.err
    assert len(check.lines) == 1, check.err
    result = run("sniff", "--eds", f"1={path}", "--seconds", "0.05", "--view", "none",
                 "-c", "eds-check")
    refused(result)
    assert str(path) in result.lines[0] and problem in result.lines[0]


def test_a_mapping_count_is_checked_before_the_loop(tmp_path: Path) -> None:
    text = PATCH.read_text().replace("DefaultValue=4\nPDOMapping=0\nLowLimit=0\nHighLimit=64",
                                     "DefaultValue=200\nPDOMapping=0\nLowLimit=0\n"
                                     "HighLimit=255", 1)
    path = tmp_path / "map.eds"
    path.write_text(text)
    check = run("eds", "check", path)
    assert check.code == 1 and "maps 200 objects; a PDO maps 0..64" in check.err
