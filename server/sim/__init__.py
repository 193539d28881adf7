"""The perceptual simulation (Jacobs et al. 2015): `Simulator` and its `Params`."""

from gazehdr.sim.params import Geometry, Params
from gazehdr.sim.simulator import BACKENDS, Simulator

__all__ = ["BACKENDS", "Geometry", "Params", "Simulator"]
