"""gcs: a MAVLink ground station and telemetry server for flight tests."""

__version__ = "0.1.0"
