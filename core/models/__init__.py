"""Gray-level models: what a pixel line sees as a function of the stage position."""

from graytrack.core.models.fourier import FourierModel
from graytrack.core.models.io import load_model, model_from_dict, model_to_dict, save_model

__all__ = ["FourierModel", "load_model", "save_model", "model_from_dict", "model_to_dict"]
