"""Reading JSON-lines captures: every line kind, written by us or by hand, and a
readable error naming the line for anything else."""

from __future__ import annotations

from pathlib import Path

import pytest

from chassis_sdk.recording.capture import read_capture

HEADER = '{"capture": 1, "port": "/dev/x", "baudrate": 115200}\n'


def write(tmp_path: Path, *lines: str) -> Path:
    path = tmp_path / "cap.jsonl"
    path.write_text(HEADER + "".join(line + "\n" for line in lines))
    return path


def test_every_line_kind_as_written_and_by_hand(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        '{"t": 0.5, "data": "edde"}',  # as json.dumps writes it
        '{"t": 0.6, "tx": "0102"}',
        '{"t": 0.7, "event": "disconnected"}',
        "",
        '{"data": "bc", "t": 0.8}',  # another key order: parsed as JSON
        '{ "t" : 0.9 ,  "data" : "ff" }',  # other spacing
        '{"t": 1, "data": "aa", "note": "kept"}',  # an extra field
    )
    assert list(read_capture(path)) == [
        (0.5, b"\xed\xde"),
        (0.8, b"\xbc"),
        (0.9, b"\xff"),
        (1.0, b"\xaa"),
    ]
    assert list(read_capture(path, sent=True)) == [(0.6, b"\x01\x02")]


@pytest.mark.parametrize(
    "line",
    [
        '{"t": 0.5, "data": "zz"}',  # not hex
        '{"t": "soon", "data": "aa"}',  # not a time
        '{"t": 0.5}',  # no bytes, no event
        '{"t": 0.5, "data": "aa"',  # cut off
        "garbage",
        "[1, 2]",
    ],
)
def test_a_bad_line_is_an_error_naming_it(tmp_path: Path, line: str) -> None:
    path = write(tmp_path, '{"t": 0.1, "data": "aa"}', line)
    with pytest.raises(ValueError, match=r"cap\.jsonl:3: not a capture line"):
        list(read_capture(path))


def test_a_file_that_is_not_a_capture(tmp_path: Path) -> None:
    path = tmp_path / "other.jsonl"
    path.write_text('{"hello": 1}\n')
    with pytest.raises(
        ValueError, match=r"not a chassis-sdk capture \(neither JSON lines nor MCAP\)"
    ):
        list(read_capture(path))
