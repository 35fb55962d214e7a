"""The cyclic collector held off for a block (core/collector.py): as it was afterwards, errors included."""

import gc

import pytest

from graytrack.core.collector import collector_paused

pytestmark = pytest.mark.unit


def test_the_collector_is_off_in_the_block_and_on_again_after_it():
    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled()
    assert gc.isenabled()


def test_an_error_in_the_block_leaves_the_collector_as_it_was():
    with pytest.raises(RuntimeError):
        with collector_paused():
            raise RuntimeError("the block failed")
    assert gc.isenabled()


def test_a_collector_that_was_off_stays_off():
    gc.disable()
    try:
        with collector_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_the_track_command_leaves_the_collector_on(tmp_path, paper_cal, paper_val):
    """The command holds it off while it tracks and writes, and turns it on again after."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.models.io import save_model
    from graytrack.core.recording import save
    from graytrack.service.cli import main as cli

    model = calibrate(paper_cal, "paper").model
    save_model(model, tmp_path / "model.json")
    save(paper_val, tmp_path / "run.npz")
    assert cli(["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "model.json"), "--out",
                str(tmp_path / "out.csv"), "--engine", "estimator"]) == 0
    assert gc.isenabled()
    assert (tmp_path / "out.csv").read_text().count("\n") == len(paper_val.t) + 1
