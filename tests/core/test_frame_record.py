"""One declaration per per-frame quantity (core/frame_record.py: name with unit, type, meaning) and
every view held to it: the solver's solution, the monitor's sign, the live fix, the batch result, the
client's position, the wire's fit figures, the CSV's columns. No renames, no second description, and
the live path and the batch path give one frame the same record."""

from __future__ import annotations

import ast
import dataclasses
import io
import tokenize
from pathlib import Path

import numpy as np
import pytest

from graytrack.core import frame_record
from graytrack.core.frame_record import BY_NAME, QUANTITIES, SOLVER_UNITS
from graytrack.core.solvers import FrameSolution
from graytrack.core.tracking import SOLUTION_SIGNS, LiveFix, TrackResult
from graytrack.core.validity import FrameSign

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
# The views: where a frame's quantities are fields of a class (file, class).
VIEWS = {"LiveFix": "core/tracking.py", "TrackResult": "core/tracking.py", "FrameSign": "core/validity.py",
         "FrameSolution": "core/solvers.py", "Position": "graytrack/client/stream.py"}
SCALAR = {float: {"float"}, int: {"int"}, bool: {"bool"}, str: {"str | None"}}
CARRIED = {"slide_sigma_um", "trim_um", "trim_sigma_um"}  # appended by their producers where they exist


def in_core(name: str) -> str:
    """The field a core view uses for ``name`` (the bound in the solver's unit)."""
    return SOLVER_UNITS.get(name, (name, 1.0))[0]


def annotations(cls: type) -> dict[str, str]:
    return {f.name: str(f.type) for f in dataclasses.fields(cls)}


def test_the_record_declares_each_quantity_once_with_a_unit_a_type_and_a_meaning() -> None:
    names = [q.name for q in QUANTITIES]
    assert len(names) == len(set(names)) == len(BY_NAME)
    for quantity in QUANTITIES:
        assert quantity.kind in SCALAR and len(quantity.description) > 15, quantity
        assert quantity.kind is not float or quantity.name.rsplit("_", 1)[-1] in {"mm", "um", "gray", "px2", "chi2"} \
            or quantity.name == "gain", f"{quantity.name}: a figure names its unit"


def test_the_live_fix_and_the_batch_result_carry_every_quantity_under_its_name_and_type() -> None:
    live, batch = annotations(LiveFix), annotations(TrackResult)
    for quantity in QUANTITIES:
        name = in_core(quantity.name)
        if quantity.name not in CARRIED:
            assert live.get(name) in SCALAR[quantity.kind] | ({"float | None"} if quantity.kind is str else set()) \
                or (quantity.kind is str and live.get(name) == "str | None"), (name, live.get(name))
        if quantity.name not in {"trim_um", "trim_sigma_um"}:
            assert batch.get(name) in {"np.ndarray", "np.ndarray | None"}, (name, batch.get(name))


def test_solution_and_sign_share_their_quantities_under_one_name_and_type() -> None:
    solution, sign = annotations(FrameSolution), annotations(FrameSign)
    for name in SOLUTION_SIGNS:
        assert solution[name] == sign[name], (name, solution[name], sign[name])
        if name in BY_NAME:
            assert solution[name] in SCALAR[BY_NAME[name].kind], name
    assert not {"offset", "rejected"} & (set(solution) | set(sign)), "renamed aliases are gone"


def test_the_wire_and_the_csv_are_made_from_the_record() -> None:
    from graytrack.client.stream import Position
    from graytrack.service.commands.track import csv_columns
    from graytrack.wire import FitFigures

    assert tuple(FitFigures.model_fields) == frame_record.FIT
    csv_record = [name for name in csv_columns()[0] if name in BY_NAME]
    assert csv_record == [q.name for q in QUANTITIES if q.csv and q.name != "texture_px"]
    position = annotations(Position)
    for name in set(position) & set(BY_NAME):
        kind = BY_NAME[name].kind
        assert position[name] in ({"float | None"} if kind is float else SCALAR[kind]), (name, position[name])


def test_a_quantity_is_described_in_the_record_alone() -> None:
    """The list of definitions: each view's field of a record quantity carries no description of its own
    (a comment on its line), so a meaning is written once."""
    names = set(BY_NAME) | {attribute for attribute, _ in SOLVER_UNITS.values()}
    described = []
    for view, path in VIEWS.items():
        source = (REPO / path).read_text()
        lines = source.split("\n")
        (cls,) = [n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ClassDef) and n.name == view]
        for statement in cls.body:
            if isinstance(statement, ast.AnnAssign) and getattr(statement.target, "id", None) in names:
                line = lines[statement.lineno - 1]
                tokens = tokenize.generate_tokens(io.StringIO(line + "\n").readline)
                if any(token.type == tokenize.COMMENT for token in tokens):
                    described.append(f"{path}:{statement.lineno} {view}.{statement.target.id}")
    assert described == []


def test_the_live_and_the_batch_path_give_a_frame_the_same_record() -> None:
    from graytrack.core.calibration import calibrate
    from graytrack.core.tracking import LiveTracker, track
    from graytrack.drivers.sim.scenarios import build_rig

    calibration, _ = build_rig("paper", "", seed=3).record(1.0)
    run, _ = build_rig("paper", "dust:count=3", seed=3, run=1).record(0.25)
    model = calibrate(calibration, model="paper").model
    result = track(model, run, reference=run.reference, light="auto", robust=True, learn=True)  # as the live one
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    fixes = [live.update(frame, reference) for frame, reference in zip(run.frames, run.reference)]
    for k in (0, len(fixes) // 2, len(fixes) - 1):
        batch, one = frame_record.of_frame(result, k), frame_record.of_frame(fixes[k])
        shared = set(batch) & set(one)
        assert shared >= {"x_mm", "crlb_um", "chi2", "gain", "offset_gray", "rejected_px", "stale"}
        for name in shared:
            if BY_NAME[name].kind is float and batch[name] is not None:
                assert one[name] == pytest.approx(batch[name], rel=1e-6, abs=1e-9), name
            else:
                assert one[name] == batch[name], name
    assert np.isfinite(result.x_mm).all()
