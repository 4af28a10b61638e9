"""``twin linearize``: a robot's linearised model as the JSON the command prints
(:mod:`twin.plant.linearize`: the model, its operating point, the JSON)."""
from __future__ import annotations

from twin.plant.linearize import MAX_DT, model_json

__all__ = ["MAX_DT", "model_json"]
