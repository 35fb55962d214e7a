"""What ``graytrack track`` says besides its summary (a reversed pixel axis, the grating moved to
mid-exposure) reaches a batch's summary row: a worker's stdout is nobody's, so nothing is printed there."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.models import save_model
from graytrack.core.recording import Recording, save
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.batch.discover import Source
from graytrack.service.batch.jobs import Job, run_job
from graytrack.service.batch.summary import COLUMNS


def test_a_track_jobs_notes_are_its_rows_not_its_stdout(tmp_path: Path, capsys) -> None:
    calibration, _ = build_rig("paper", "", seed=11).record(1.0)
    model = calibrate(calibration, "paper").model
    # calibrated on a camera mounted the other way round, with the grating latched 2 ms off mid-exposure
    model = model.with_changes(info={**model.info, "flip": True, "reference_skew_s": 0.002})
    measured, _ = build_rig("paper", "", seed=12).record(1.0)
    reversed_camera = Recording(np.ascontiguousarray(measured.frames[..., ::-1]), measured.t, measured.reference,
                                {key: value for key, value in measured.meta.items() if "revers" not in key})
    save(reversed_camera, tmp_path / "run.npz")
    save_model(model, tmp_path / "model.json")

    row = run_job(Job("track", Source(tmp_path / "run.npz", "run"), str(tmp_path / "out")))

    assert row["status"] == "ok", row["reason"]
    assert int(row["locked"]) == measured.n_frames  # oriented as the model expects: every frame placed
    assert row["notes"] == ("flip pixel axis reversed: the model was calibrated with --flip; "
                            "grating reference moved to mid-exposure (+2.000 ms, from the model)")
    assert list(row) == list(COLUMNS) and COLUMNS[-1] == "notes"
    assert capsys.readouterr().out == ""
