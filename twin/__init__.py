"""mtwip-twin: a digital twin of a mobile two-wheeled inverted pendulum under IT2 fuzzy control.

Data flow: plant (``twin.plant``) -> sensors -> estimator (``estimation``) ->
controllers (``twin.controllers``, built on ``twin.fuzzy``) -> actuators -> plant.
"""
from twin.errors import InfeasibleDesign, TwinError
from twin.params import NOMINAL, RobotParams

__version__ = "0.1.0"
__all__ = ["NOMINAL", "RobotParams", "TwinError", "InfeasibleDesign", "__version__"]
