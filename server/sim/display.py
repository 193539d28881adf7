"""The display model: what a display value means in cd/m² on a monitor.

The simulator returns display values `v = J^γ` (Appendix A's γ = 0.455) for a monitor whose
response undoes that, so that J is linear light, J = 1 its white. Its luminances in cd/m² are
then `white · v^gamma` with gamma = 1/γ. The model's own monitor is `PAPER_DISPLAY`: a white of
100 cd/m² (Sec. 2.4's dimly lit office, the adaptation floor) and the response v^(1/0.455), on
which Sec. 4.1's afterimages come out as the authors measured them with a spectroradiometer
(2.2·10⁻² and 6.5·10⁻² cd/m², docs/model.md, "Presets"). An experiment states its lab's monitor
(`[display] white, gamma` of a design) and shows the paper's cd/m² on it (`experiment.stimulus`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gazehdr.drivers.errors import InputError
from gazehdr.sim.params import Params


@dataclass(frozen=True)
class DisplayModel:
    """A monitor: white luminance `white_cd_m2` at v = 1, luminance white · v^gamma."""

    white_cd_m2: float = 100.0
    gamma: float = 1.0 / Params().gamma  # the monitor the paper's γ compensates: 2.198

    def __post_init__(self) -> None:
        for name in ("white_cd_m2", "gamma"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"display {name} must be a finite positive number, got {value}")

    def cd_m2(self, v: np.ndarray) -> np.ndarray:
        """cd/m² of display values `v` (per channel; luminance: weight them with w_P)."""
        return self.white_cd_m2 * np.power(np.clip(np.asarray(v, np.float64), 0.0, 1.0), self.gamma)

    def values(self, cd_m2: np.ndarray) -> np.ndarray:
        """The display values that show `cd_m2` (per channel), clipped to the monitor's white."""
        relative = np.clip(np.asarray(cd_m2, np.float64) / self.white_cd_m2, 0.0, 1.0)
        return np.power(relative, 1.0 / self.gamma)


#: The monitor the model's frames are made for, on which the paper's numbers come out.
PAPER_DISPLAY = DisplayModel()
