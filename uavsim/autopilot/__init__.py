"""Gains out: identified PD gains as autopilot parameter files (PX4 ``.params``, ArduPilot ``.parm``).

See ``uavsim.autopilot.params`` for the unit mapping and the parameter names.

    from uavsim.autopilot import export_gains, write_params
    write_params(export_gains(ans, "ardupilot", cmd_scale=1.0), "roll.parm")
"""

from uavsim.autopilot.params import (
    AUTOPILOTS,
    MAPPING,
    GainExport,
    Param,
    export_gains,
    format_params,
    read_params,
    write_params,
)

__all__ = ["AUTOPILOTS", "MAPPING", "GainExport", "Param", "export_gains", "format_params", "read_params",
           "write_params"]
