"""The batched DeepRacer simulator: car dynamics, AWS episode rules, reward params, observations.

`Simulator` steps the cars; `World` adds the observation, the action mapping and the reward, and is
what training, evaluation and the Gymnasium adapters drive. The car state is read by name through
`Simulator.state` / `Simulator.judged` (`CarState`), episode statuses are `Status` codes (AWS names in
`STATUS_NAMES`), and `Simulator.trace_columns` gives the simtrace columns (`TRACE_COLUMNS`).
"""

from racerlab.sim.core import Simulator, StartRules
from racerlab.sim.state import TRACE_COLUMNS, CarState, Status
from racerlab.sim.world import World, car_for

# the simulator's constants and cars, defined in spec
from racerlab.spec import SIMULATORS, STATUS_NAMES, STEP_S, CarParams, car_params

__all__ = ["SIMULATORS", "STATUS_NAMES", "STEP_S", "TRACE_COLUMNS", "CarParams", "CarState", "Simulator", "StartRules",
           "Status", "World", "car_for", "car_params"]
