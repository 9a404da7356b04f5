"""Exception type of twin_mapping."""
from calib.errors import CalibError


class TwinError(CalibError, ValueError):
    """A digital-twin parameter set is invalid or cannot be mapped."""
