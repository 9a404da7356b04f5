"""Exception type of reports: ``ReportError``, its one error root (a ``ValueError``; also a
``calib.errors.CalibError``, as it always was, for callers that catch calib's errors)."""
from calib.errors import CalibError


class ReportError(CalibError):
    """Inputs of a report are missing, mismatched or unreadable."""
