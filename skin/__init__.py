"""canskin core: the exact tripod sensor model, constants, errors and the CLI."""

from skin.constants import AXES, DEFAULT_CONSTANTS, PILLARS, SensorConstants
from skin.errors import (
    BusError,
    ConfigError,
    DatasetError,
    DecodeError,
    ModelFileError,
    NotFittedError,
    SkinError,
    StrainLimitError,
)

__version__ = "0.1.0"

__all__ = [
    "AXES",
    "DEFAULT_CONSTANTS",
    "PILLARS",
    "BusError",
    "ConfigError",
    "DatasetError",
    "DecodeError",
    "ModelFileError",
    "NotFittedError",
    "SensorConstants",
    "SkinError",
    "StrainLimitError",
    "__version__",
]
