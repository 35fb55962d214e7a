"""The simulated controller's interpreter, without I/O: referencing, status bytes, parameters, help."""

from __future__ import annotations

import pytest

from graytrack.drivers.stage.axis_model import TrapezoidAxis
from graytrack.drivers.stage.sim_gcs import BUSY, READY, SimGCSInterpreter


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def sim(clock: Clock) -> SimGCSInterpreter:
    return SimGCSInterpreter(TrapezoidAxis(start_mm=2.0, velocity_mm_s=10.0), clock, reference_mm=12.5)


def test_reference_move_keeps_the_controller_busy_until_it_ends(sim: SimGCSInterpreter, clock: Clock) -> None:
    sim.execute("SVO 1 1")
    assert sim.execute_single(7) == [READY]
    sim.execute("FRF 1")
    assert sim.execute_single(7) == [BUSY] and sim.execute("FRF? 1") == ["1=0"]
    assert sim.execute_single(5) == ["1"] and sim.execute_single(4) == ["0x7000"]  # referencing, moving, servo
    sim.execute("MOV 1 3.0")
    assert sim.execute("ERR?") == ["5"], "no absolute move before the reference is known"
    clock.t = 2.0  # 10.5 mm at 10 mm/s is over
    assert sim.execute_single(7) == [READY] and sim.execute("FRF? 1") == ["1=1"]
    assert sim.execute("POS? 1") == ["1=12.5"] and sim.execute_single(4) == ["0x9000"]


def test_a_stop_aborts_referencing_and_leaves_error_10(sim: SimGCSInterpreter, clock: Clock) -> None:
    sim.execute("SVO 1 1")
    sim.execute("FRF 1")
    clock.t = 0.2
    assert sim.execute_single(24) is None
    assert sim.execute_single(4) == ["0x9100"]  # servo on, on target (stopped at once), error flag
    assert sim.execute("ERR?") == ["10"]
    clock.t = 5.0
    assert sim.execute("FRF? 1") == ["1=0"] and sim.execute_single(7) == [READY]


def test_unknown_single_characters_and_hash_lines_are_unknown_commands(sim: SimGCSInterpreter) -> None:
    assert sim.execute_single(3) is None and sim.execute("ERR?") == ["2"]
    assert sim.execute("#5") is None and sim.execute("ERR?") == ["2"], "#5 is a byte, not a text line"


def test_queries_check_unknown_axes_before_their_count(sim: SimGCSInterpreter) -> None:
    assert sim.execute("POS? 1 2") is None and sim.execute("ERR?") == ["15"]
    assert sim.execute("POS? 1 1") is None and sim.execute("ERR?") == ["24"]
    assert sim.execute("MOV 2 1.0") is None and sim.execute("ERR?") == ["15"]


def test_help_lists_every_command_once_between_header_and_footer(sim: SimGCSInterpreter) -> None:
    lines = sim.execute("HLP?")
    assert lines is not None and lines[0].startswith("The following") and lines[-1] == "end of help"
    names = [line.split()[0] for line in lines[1:-1]]
    assert len(names) == len(set(names)) and {"#5", "#7", "#24", "CST?", "HPA?", "VER?"} <= set(names)
    for name in names:
        if not name.startswith("#") and name not in ("CST", "FRF", "HLT", "MOV", "MVR", "STP", "SVO", "VEL"):
            assert sim.execute(name) is not None, f"{name} is listed but does not answer without arguments"


def test_every_listed_parameter_is_readable(sim: SimGCSInterpreter) -> None:
    listing = sim.execute("HPA?")
    assert listing is not None
    for line in listing[1:-1]:
        parameter = line.split("=")[0]
        (reply,) = sim.execute(f"SPA? 1 {parameter}") or [""]
        assert reply.startswith(f"1 {parameter}=")
    assert sim.execute("SPA? 1 0x99") is None and sim.execute("ERR?") == ["54"]
    sim.execute("CST 1 M-TEST")
    assert sim.execute("CST?") == ["1=M-TEST"] and sim.execute("SPA? 1 0x3C") == ["1 0x3C=M-TEST"]
