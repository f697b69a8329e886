"""The strict reading of a command from the network, its timestamp, and refusal reports
(chassis_sdk.integrations.inbound), shared by every surface that takes commands: a readable table of
what is refused and why, properties over arbitrary bytes, and the report schedule."""

from __future__ import annotations

import json
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from chassis_sdk.integrations.inbound import (
    MAX_COMMAND_BYTES,
    CommandError,
    Refusals,
    check_fresh,
    command_object,
    command_time,
)

REFUSED = [
    pytest.param(b"[" * 100_000 + b"]" * 100_000, "too deeply|bytes", id="nested-100000-deep"),
    pytest.param(
        b'{"linear":' + b"[" * 2000 + b"]" * 2000 + b"}", "nested too deeply", id="nested-2000"
    ),
    pytest.param(b'{"linear":' + b"9" * 4000 + b"}", "4000 characters", id="4000-digit-integer"),
    pytest.param(b'{"linear":' + b"9" * 5000 + b"}", "5011 bytes", id="5000-digit-integer"),
    pytest.param(b'{"linear":' + b"9" * 400 + b"}", "400 characters", id="400-digit-integer"),
    pytest.param(b'{"linear":0.' + b"1" * 100 + b"}", "characters", id="100-digit-fraction"),
    pytest.param('{"linear":0.3}'.encode("utf-16"), "not UTF-8", id="utf-16-with-bom"),
    pytest.param('{"linear":0.3}'.encode("utf-16-le"), "not JSON", id="utf-16-le"),
    pytest.param('{"linear":0.3}'.encode("utf-32"), "not UTF-8", id="utf-32"),
    pytest.param(b"\xef\xbb\xbf{}", "byte order mark", id="utf-8-bom"),
    pytest.param(b'{"linear":0.3,"linear":0}', "appears twice", id="duplicate-key"),
    pytest.param(b'{"a":{"x":1,"x":2}}', "appears twice", id="duplicate-nested-key"),
    pytest.param(b'{"linear":NaN}', "NaN", id="nan"),
    pytest.param(b'{"linear":-Infinity}', "Infinity", id="infinity"),
    pytest.param(b"[0.3, 0]", "list, not an object", id="array"),
    pytest.param(b'"go"', "str, not an object", id="string"),
    pytest.param(b"", "not JSON", id="empty"),
    pytest.param(b'{"linear":0.3', "not JSON", id="truncated"),
    pytest.param(b'{"linear":0.3} {}', "not JSON", id="trailing-data"),
    pytest.param(b"\xff\xfe\xfd", "not UTF-8", id="binary"),
    pytest.param(b" " * (MAX_COMMAND_BYTES + 1), "bytes; a command is at most", id="too-long"),
]


@pytest.mark.parametrize(("raw", "why"), REFUSED)
def test_what_is_refused_and_why(raw: bytes, why: str) -> None:
    with pytest.raises(CommandError, match=why):
        command_object(raw)


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        (b'{"linear": 0.3, "angular": -1}', {"linear": 0.3, "angular": -1}),
        (b'{"linear":1e309}', {"linear": float("inf")}),  # finite checks come after
        (b'{"engaged": true}', {"engaged": True}),
        (bytearray(b'{"a": "\\u00e9"}'), {"a": "é"}),
        (memoryview(b"{}"), {}),
    ],
)
def test_well_formed_commands_are_read(raw: bytes, expected: dict[str, object]) -> None:
    assert command_object(raw) == expected


def test_a_payload_that_is_not_bytes_is_refused() -> None:
    with pytest.raises(CommandError, match="not bytes"):
        command_object("{}")


@given(st.binary(max_size=512))
def test_any_bytes_give_an_object_or_a_command_error(raw: bytes) -> None:
    try:
        result: object = command_object(raw)
    except CommandError as exc:
        result = str(exc)
    assert isinstance(result, dict) or "\n" not in str(result)


@given(
    st.dictionaries(
        st.text(max_size=8),
        st.one_of(
            st.none(),
            st.booleans(),
            st.integers(-(10**15), 10**15),
            st.floats(allow_nan=False, allow_infinity=False),
        ),
        max_size=8,
    )
)
def test_what_json_dumps_writes_reads_back(obj: dict[str, object]) -> None:
    assert command_object(json.dumps(obj).encode()) == obj


@pytest.mark.parametrize(
    ("value", "seconds"),
    [
        ("2026-12-01T18:00:00.250Z", 1796148000.25),
        ("2026-12-01T19:00:00.250+01:00", 1796148000.25),
        (1796148000.25, 1796148000.25),
        (1796148000, 1796148000.0),
    ],
)
def test_timestamps_iso_8601_or_epoch_seconds(value: object, seconds: float) -> None:
    assert command_time(value) == pytest.approx(seconds)


@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("2026-12-01T18:00:00", "UTC offset"),
        ("yesterday", "not an ISO 8601"),
        ("2" * 100, "too long"),
        (True, "epoch seconds or an ISO 8601"),
        (None, "epoch seconds or an ISO 8601"),
        (-1, "positive"),
        (float("nan"), "positive"),
    ],
)
def test_bad_timestamps_are_refused(value: object, why: str) -> None:
    with pytest.raises(CommandError, match=why):
        command_time(value)


def test_a_command_older_than_the_deadman_or_from_the_future_is_refused() -> None:
    now = time.time()
    assert check_fresh(now - 0.4, 0.5, now=now) == pytest.approx(0.4)
    assert check_fresh(now - 0.7, 0.5, now=now) == pytest.approx(0.7)  # within the skew
    with pytest.raises(CommandError, match="old"):
        check_fresh(now - 0.8, 0.5, now=now)
    with pytest.raises(CommandError, match="future"):
        check_fresh(now + 1.0, 0.5, now=now)


def test_refusals_report_the_first_at_once_then_one_summary_per_interval() -> None:
    clock = [100.0]
    refusals = Refusals(1.0, clock=lambda: clock[0])
    first = refusals.add("r1/cmd/velocity", "not JSON")
    assert first is not None
    assert (first.count, first.total) == (1, 1)
    assert first.summary() == "r1/cmd/velocity: not JSON"
    for i in range(999):
        assert refusals.add("r1/cmd/velocity", "not JSON" if i % 2 else "duplicate") is None
    assert refusals.pending == 999
    assert refusals.due() is None  # not yet an interval since the first
    clock[0] += 1.0
    report = refusals.due()
    assert report is not None
    assert (report.count, report.total) == (999, 1000)
    assert report.reasons == {"duplicate": 500, "not JSON": 499}
    assert report.summary().startswith("999 refused, latest r1/cmd/velocity")
    assert refusals.due() is None


def test_refusal_reasons_are_counted_by_their_text_without_numbers() -> None:
    clock = [0.0]
    refusals = Refusals(1.0, clock=lambda: clock[0])
    refusals.add("t", "first")
    for age in (0.81, 0.9, 1.25, 30.0):
        refusals.add("t", f"the command is {age:.3f} s old (older than 0.5 s + 0.25 s skew)")
    clock[0] = 5.0
    report = refusals.due()
    assert report is not None
    assert report.reasons == {"the command is N s old (older than N s + N s skew)": 4}
    assert report.why.startswith("the command is 30.000 s old")  # the latest, as it was


def test_refusals_keep_at_most_eight_reasons() -> None:
    clock = [0.0]
    refusals = Refusals(1.0, clock=lambda: clock[0])
    refusals.add("t", "first")
    for i in range(20):
        refusals.add("t", f"reason {chr(ord('a') + i)}")
    clock[0] = 5.0
    report = refusals.due()
    assert report is not None
    assert report.count == 20
    assert len(report.reasons) == 8
    assert report.unlisted == 12


def test_refusals_need_a_positive_interval() -> None:
    with pytest.raises(ValueError, match="interval"):
        Refusals(0)
