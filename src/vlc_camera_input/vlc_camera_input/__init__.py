"""Real camera input: a side-by-side stereo UVC camera split into the graph's left and
right images and camera_info.
"""
