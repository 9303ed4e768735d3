"""Colours and sizes shared by the markers and the pictures (RGBA, 0–1; metres)."""
from vlc_view.core.scene import LAMP_IDENTIFIED_NOW, LAMP_NOT_SEEN, LAMP_SEEN_RECENTLY

LAMP_COLOURS = {
    LAMP_IDENTIFIED_NOW: (0.10, 0.80, 0.20, 1.0),     # green
    LAMP_SEEN_RECENTLY: (1.00, 0.65, 0.00, 1.0),      # amber
    LAMP_NOT_SEEN: (0.55, 0.55, 0.55, 0.6),           # grey
}
TRAIN_COLOUR = (0.15, 0.35, 0.85, 0.35)               # translucent blue body
HEADING_COLOUR = (0.15, 0.35, 0.85, 1.0)
BAR_COLOUR = (0.90, 0.10, 0.10, 1.0)                  # red: along-track ±3σ
RAY_COLOUR = (0.00, 0.75, 0.90, 1.0)                  # cyan: camera → lamp
CAMERA_COLOUR = (0.00, 0.45, 0.60, 1.0)
TRACK_COLOUR = (0.30, 0.30, 0.30, 1.0)

#: Train head drawn as a box behind base_link (x back from the head, y across, z up), m.
TRAIN_BOX_M = (4.0, 2.8, 3.6)
HEADING_ARROW_M = 2.0
RAY_WIDTH_M = 0.02
BAR_WIDTH_M = 0.06
#: The ±3σ bar is drawn at least this long, so a 1 cm bar still shows, m.
BAR_MIN_HALF_LENGTH_M = 0.05
