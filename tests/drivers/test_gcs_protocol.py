"""GCS wire rules without any I/O: command formatting, reply framing, value parsing."""

from __future__ import annotations

import pytest

from graytrack.drivers.stage import gcs_protocol as gcs


def test_commands_are_single_lf_terminated_lines_with_plain_decimals() -> None:
    assert gcs.format_command("MOV", "1", 12.5) == b"MOV 1 12.5\n"
    assert gcs.format_command("MVR", "1", -1e-7) == b"MVR 1 -0.0000001\n"
    assert gcs.format_command("ERR?") == b"ERR?\n"
    with pytest.raises(ValueError):
        gcs.format_command("MOV", "1", float("nan"))
    with pytest.raises(ValueError):
        gcs.format_command("MOV 1 2\nSTP")


def test_framer_joins_chunks_and_continuation_lines() -> None:
    framer = gcs.ReplyFramer()
    assert framer.feed(b"1=1.5") == []
    assert framer.pending()
    assert framer.feed(b" \n2=") == []
    assert framer.feed(b"3.25\n0\n") == [["1=1.5", "2=3.25"], ["0"]]
    assert not framer.pending()


def test_framer_turns_noise_into_a_malformed_line_not_an_exception() -> None:
    framer = gcs.ReplyFramer()
    (reply,) = framer.feed(b"\xff\xfe\x001=2.0\n")
    with pytest.raises(ValueError):
        gcs.parse_axis_float(gcs.single_line(reply), "1")


@pytest.mark.parametrize(
    ("line", "ok"),
    [("1=2.5", 2.5), ("1=-0.000001", -1e-6), ("2=2.5", None), ("1=abc", None), ("1=nan", None), ("=3", None)],
)
def test_axis_values_must_name_the_axis_asked_for(line: str, ok: float | None) -> None:
    if ok is None:
        with pytest.raises(ValueError):
            gcs.parse_axis_float(line, "1")
    else:
        assert gcs.parse_axis_float(line, "1") == ok


def test_error_codes_and_booleans() -> None:
    assert gcs.parse_error_code("0") == 0
    assert gcs.parse_error_code("  17 ") == 17
    with pytest.raises(ValueError):
        gcs.parse_error_code("1=0")
    assert gcs.parse_axis_bool("1=1", "1") is True
    with pytest.raises(ValueError):
        gcs.parse_axis_bool("1=2", "1")


def test_command_framer_takes_single_character_commands_out_of_a_half_received_line() -> None:
    framer = gcs.CommandFramer()
    assert framer.feed(b"\x05") == [5]  # #5 needs no line end
    assert framer.feed(b"*ID") == []
    assert framer.feed(b"N\x07?\r\nPOS? 1\n\x18") == [7, "*IDN?", "POS? 1", 24]
    assert framer.feed(b"MOV 1\t2\n") == ["MOV 1\t2"], "tab and CR are blanks of a line, not commands"
