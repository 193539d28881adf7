"""What a scene is to the rest of gazehdr (the protocol every scene implements)."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Scene(Protocol):
    name: str
    #: True when `render` depends on `t` (the caller must re-render every frame).
    animated: bool

    def render(self, t: float, width: int, height: int) -> np.ndarray: ...

    def state_at(self, t: float) -> object:
        """A hashable that changes exactly when `render`'s output does (None: never)."""
        ...

    def next_change(self, t: float) -> float | None:
        """The first time after `t` at which `state_at` changes (None: never), so that a caller
        stepping in long frames can split a step there and miss no brief flash."""
        ...
