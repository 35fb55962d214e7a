"""Read and checked, the account the recursion carries where the grating refutes a frame's own.

A model that no longer fits the print (its tone curve changed since calibration, a lens refocused) fits a frame best
somewhere the grating refutes: on the paper rig a light's jump took the second frame's account 387 µm off, and the
recursion carried it on for a hundred frames while the focus and the light's shape bent to keep it (389 µm rms over
the run, 137 µm for the lens). An account that needed a jump to explain its frame, or explains it not at all, has no
claim against the grating: the frames after it go on from the grating's account, and where no account pinned to the
grating explains the frame either, from the one with no state jumped; the frames are flagged as the model's failure
they are."""

from __future__ import annotations

import pytest

from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import estimator_figures, rig_model

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def paper():
    return rig_model("paper")


@pytest.mark.parametrize("later", ["print_gamma", "magnification"])
def test_a_model_that_no_longer_fits_the_print_is_followed_where_the_grating_finds_the_carriage(paper, later):
    run, truth = build_rig("paper", later, seed=3, run=1).record(10.0)
    figures = estimator_figures(paper, run, truth, "check")
    assert figures["std"] < 80.0, figures  # µm (50 and 50 measured; the account refuted carried: 389 and 137)
    assert figures["flagged"] > 0.2, figures  # (the model's failure, said: 45-58 % of the frames)
    assert figures["silent"] <= 0.005 * truth.x_mm.size, figures
