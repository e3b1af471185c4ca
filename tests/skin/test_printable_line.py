"""Text from a broken file, in an error line, stays one printable line."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from skin.errors import printable_line


@given(st.text())
def test_any_text_is_one_printable_line(text: str) -> None:
    line = printable_line(text)
    assert len(line.splitlines()) <= 1
    assert line.isprintable()


@given(st.text(alphabet=st.characters(categories=["L", "N", "P"]), min_size=1))
def test_plain_words_are_kept_as_they_are(text: str) -> None:
    assert printable_line(f"  {text}\n") == text
