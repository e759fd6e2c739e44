"""uav-harness's example missions, installed as ``harness.examples``: unmodified MAVSDK, DroneKit and pymavlink
scripts that ``harness run --mission`` flies. They are scripts, not modules to import: ``harness examples``
lists them and ``harness examples copy NAME`` puts one in the current folder."""
