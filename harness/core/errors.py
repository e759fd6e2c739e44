"""The project's error hierarchy: one root, bad setup versus failures at run time."""


class HarnessError(Exception):
    """Root of every error the harness raises on purpose."""


class ScenarioError(HarnessError):
    """The run was set up wrongly: a bad scenario file, option or argument. Says what and where."""


class SimulationError(HarnessError):
    """Something failed while the simulation ran: a peer died, stalled or broke the protocol."""
