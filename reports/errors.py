"""Exception type of reports."""
from calib.errors import CalibError


class ReportError(CalibError, ValueError):
    """Inputs of a report are missing, mismatched or unreadable."""
