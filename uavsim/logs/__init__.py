"""Flight logs in: a PX4 ULog, an ArduPilot DataFlash log or a ROS 2 bag as a flight session.

The user names where r, y and u are in the log (or picks a preset for the
common loops), and the relay run's parameters; the importer reads the three
series with the format's own library (pyulog, pymavlink, rosbags), checks
them (time strictly increasing, no gap, logged at least at the control rate,
finite), cuts the relay segment (given, or detected: the longest stretch where
u takes only its two relay levels), samples them onto the control-rate grid
(the last logged value at each tick: the controller's view) and writes a
``uavsim-session/1`` folder that ``uavsim identify`` reads.

A field is named ``TOPIC.FIELD`` (ULog: ``vehicle_local_position.z``, arrays as
``xyz[2]``; DataFlash: ``CTUN.Alt``; ROS 2: ``/topic.pose.position.z``),
optionally wrapped: ``-X`` (negated), ``rad(X)`` (degrees to radians),
``roll(TOPIC.q)`` / ``pitch(TOPIC.q)`` (from a quaternion w, x, y, z), or a
number (a constant, e.g. a fixed reference).

    from uavsim.logs import import_log
    session = import_log("flight.ulg", "out/flight", preset="px4-altitude", kind="np-mrft", beta=-0.73,
                         tau_obs=0.02, a_n=0.002)

Presets (loop; r, y, u):

===================  ========  ===============================================================
px4-altitude         altitude  -trajectory_setpoint.position[2], -vehicle_local_position.z,
                               -vehicle_thrust_setpoint.xyz[2] (normalized thrust, up)
px4-roll / -pitch    roll      roll(vehicle_attitude_setpoint.q_d), roll(vehicle_attitude.q),
                               vehicle_torque_setpoint.xyz[0] (normalized torque); pitch: [1]
ardupilot-altitude   altitude  CTUN.DAlt, CTUN.Alt (m), CTUN.ThO (throttle 0..1)
ardupilot-roll       roll      rad(ATT.DesRoll), rad(ATT.Roll), RATE.ROut (normalized)
ardupilot-pitch      pitch     rad(ATT.DesPitch), rad(ATT.Pitch), RATE.POut
===================  ========  ===============================================================
"""

from uavsim.logs.importer import (
    FORMATS,
    PRESETS,
    LogError,
    Preset,
    detect_format,
    detect_relay,
    import_log,
    read_series,
)

__all__ = ["FORMATS", "PRESETS", "LogError", "Preset", "detect_format", "detect_relay", "import_log", "read_series"]
