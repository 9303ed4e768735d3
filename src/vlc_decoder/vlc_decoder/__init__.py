"""VLC stripe decoder: lamp spots to CRC-checked UIDs and lamp-map positions, tracked over
frames.
"""
