"""Synthetic tunnel rig: lamp world, train motion and vibration, rolling-shutter stereo VLC
renderer, ADIS16488 IMU model, ground truth.
"""
