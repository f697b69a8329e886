"""``diagnose()``'s report (kept at this path for code written against it).

The report and its findings live in :mod:`chassis_sdk.core.diagnosis`; the chassis's
findings in :mod:`chassis_sdk.devices.chassis.health`.
"""

from .core.diagnosis import Diagnosis, Findings
from .core.enums import flag_names
from .devices.chassis.health import ChassisDiagnosis

__all__ = ["ChassisDiagnosis", "Diagnosis", "Findings", "flag_names"]
