"""The project's error hierarchy: one root, bad setup versus failures at run time."""

import signal


class HarnessError(Exception):
    """Root of every error the harness raises on purpose."""


class ScenarioError(HarnessError):
    """The run was set up wrongly: a bad scenario file, option or argument. Says what and where."""


class SimulationError(HarnessError):
    """Something failed while the simulation ran: a peer died, stalled or broke the protocol."""


class StopSignal(KeyboardInterrupt):
    """A signal asked the process to stop (Ctrl-C's SIGINT, SIGTERM from a supervisor or a CI time-out), raised
    where it arrived, as Ctrl-C's KeyboardInterrupt is; ``signum`` says which, so the run can say so."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signum)


def stop_reason(exc: KeyboardInterrupt) -> str:
    """``stopped by Ctrl-C (SIGINT)``, ``stopped by SIGTERM``."""
    signum = exc.signum if isinstance(exc, StopSignal) else signal.SIGINT
    if signum == signal.SIGINT:
        return "stopped by Ctrl-C (SIGINT)"
    try:
        return f"stopped by {signal.Signals(signum).name}"
    except ValueError:
        return f"stopped by signal {signum}"
