"""Identification of the scanner model: sensorless (Secs. III.C, IV) and sensor-based."""
