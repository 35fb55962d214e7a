"""One model per row of the strip: rows that disagree (camera tilt, row shading)."""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.evidence import Evidence, explains, share_above_noise


class Rows(Effect):
    name = "rows"
    frame_part = "coefficients"  # core/frame_tables.py: what tracking reads of it
    family = "rows of the strip that disagree (camera tilt against the axis, row shading)"
    adds = "one model per row: a target shift per row and row-dependent coefficients"
    fitted = "row shift inside the variable projection, row polynomials linear"
    order = 13

    def probe(self, stage):
        """A shift (tilt), gain and offset per row, fitted on training frames, scored held out.

        The basis is block-diagonal in the row, so each row's three coefficients are solved on
        their own: a batch of 3×3 systems instead of one large least-squares problem.
        """

        train, val = stage.train, stage.val
        if val.data.frames.shape[1] < 2 or train.model.n_rows > 1:
            return None

        def design(fit):
            shape = fit.data.frames.shape
            parts = (np.broadcast_to(fit.slope, shape), np.broadcast_to(fit.smooth, shape), np.ones(shape))
            return np.stack(parts, axis=-1) * fit.usable[..., None]

        d_t, d_v = design(train), design(val)
        gram = np.einsum("krup,kruq->rpq", d_t, d_t)
        rhs = np.einsum("krup,kru->rp", d_t, train.residual)[..., None]
        coef = np.linalg.solve(gram + 1e-9 * np.eye(3), rhs)[..., 0]
        corrected = val.residual - np.einsum("krup,rp->kru", d_v, coef)
        explained = float((val.residual**2).sum() - (corrected**2).sum())
        sigma2 = val.data.sigma_gray**2
        n_rows = val.data.frames.shape[1]
        per_row_um = float(np.polyfit(np.arange(n_rows), coef[:, 0] * 1e3, 1)[0])
        share = share_above_noise(explained, train, val)  # fitted on training frames: cross-validated
        return Evidence(self.name, "row (tilt)", explained, explained / sigma2 / np.sqrt(6.0 * n_rows), share,
                        f"rows see the target shifted by {per_row_um:+.2f} µm per row (tilt); per-row terms "
                        f"{explains(share)}")

    def grow(self, spec, argument):
        return None if spec.per_row else spec.with_changes(per_row=True)


EFFECT = Rows()
