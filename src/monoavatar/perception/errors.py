"""Errors and warnings of the perception stage."""

from __future__ import annotations

from monoavatar.core.errors import MonoavatarError, format_indices


class PerceptionError(MonoavatarError, RuntimeError):
    """Perception cannot give a usable result for this input."""


class NoPersonError(PerceptionError):
    """Too few frames show a person.

    Attributes:
        frames: source indices of the frames where no person was found.
        found: how many frames show a person.
        required: how many were required.
    """

    def __init__(self, source: str, frames: list[int], found: int, required: int,
                 hint: str = "") -> None:  # fmt: skip
        self.frames = list(frames)
        self.found = found
        self.required = required
        super().__init__(
            f"{source}: a person was found in only {found} of {found + len(frames)} frame(s), "
            f"at least {required} are needed; no person in frame(s) {format_indices(self.frames)}"
            + (f". {hint}" if hint else "")
        )


class NoPersonWarning(UserWarning):
    """Some frames show no person; they are flagged in ``Observations.no_person``."""


class MultiplePeopleWarning(UserWarning):
    """Several people were seen; the most central and largest was kept."""

