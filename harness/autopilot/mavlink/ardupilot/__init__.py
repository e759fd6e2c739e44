"""The ArduCopter personality of the autopilot's MAVLink side (see ``dialect.py``)."""
