"""uav-harness. Importing it decides whether this process runs the compiled per-vehicle core or its pure-Python
source (``harness.core.native``)."""

from harness.core import native as _native

_native.install()
