"""Exceptions of twotank_validation: one root, subclasses that also inherit the builtin."""


class TwotankError(Exception):
    """Root of every error raised on purpose by this package."""


class DatumError(TwotankError, ValueError):
    """The input-output record cannot be validated as it is (length, periods, NaN, shapes)."""


class ModelError(TwotankError, ValueError):
    """A model is malformed, inconsistent with the data, or not robustly usable."""


class ModelFileError(ModelError):
    """A YAML model file is missing, unreadable or does not follow the schema."""


class DimensionError(ModelError):
    """Array or model dimensions do not match (the message names expected and found)."""


class UnstableModelError(ModelError):
    """The nominal model is unstable, so its frequency response does not describe the data."""


class SolverError(TwotankError, RuntimeError):
    """A numerical solver failed in a way that is not a property of the data."""
