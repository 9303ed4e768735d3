"""Stereo triangulation, Kalman fusion with the IMU along the track, integrity checks;
publishes the train position.
"""
