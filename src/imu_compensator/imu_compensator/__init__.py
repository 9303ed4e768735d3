"""Camera-platform attitude from the IMU and vibration/heading compensation."""
