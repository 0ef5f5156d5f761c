"""Every fitted-model kind by name (one literal mapping) and :func:`load_model`, which reads any of them."""

from __future__ import annotations

from icgo.artifacts.calibration import MagCalibration
from icgo.artifacts.discrepancy import PhysicsModel
from icgo.artifacts.format import FittedModel, read_model
from icgo.artifacts.network import GyroNetwork, GyroRELM, LookupTableModel
from icgo.artifacts.relm import MSAModel, RELMCompensation

MODEL_KINDS: dict[str, type[FittedModel]] = {cls.KIND: cls for cls in (
    MSAModel, RELMCompensation, MagCalibration, GyroNetwork, GyroRELM, LookupTableModel, PhysicsModel)}


def load_model(path) -> FittedModel:
    """Load any model saved by :meth:`~icgo.artifacts.format.FittedModel.save` (see :func:`~icgo.artifacts.format.read_model`)."""
    return read_model(path, MODEL_KINDS)
