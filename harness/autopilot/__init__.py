"""The autopilot: estimator, control cascade, flight modes, failsafes; MAVLink interface in ``mavlink``.

Import the API types from ``harness.autopilot.api`` and the class from ``harness.autopilot.autopilot``.
"""
