"""The batched DeepRacer simulator: car dynamics, AWS episode rules, reward params, observations."""

from racerlab.sim._kernels import STATUS_NAMES
from racerlab.sim.car import STEP_S, CarParams
from racerlab.sim.core import Simulator, StartRules

__all__ = ["STATUS_NAMES", "STEP_S", "CarParams", "Simulator", "StartRules"]
