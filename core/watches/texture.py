"""A frame the print's learned marks moved from where the print alone places it is flagged ``texture``.

A mark learned on the print (core/texture.py) gives its samples back to the frames that see it; learned
right, it adds information near where the print alone places the frame. Learned from positions
something had pulled (a smudge's wings, without a grating to vouch for the frames), it holds the frames
where they were pulled, with χ² at its level, and nothing else would tell: the frame says what its
answer rests on (``FrameSolution.pulled``, :meth:`Texture.pulls`).
"""

from __future__ import annotations

from graytrack.core.validity import FrameSign


class TextureWatch:
    family = "texture"
    reads = ("placed", "pulled")

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.pulled)

    def step(self, placed: bool, pulled: bool) -> str | None:
        return self.family if placed and pulled else None


def make(tracker) -> TextureWatch:
    return TextureWatch()
