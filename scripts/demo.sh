#!/usr/bin/env bash
# The main job (`make demo`, after setup): renders the rig's demo pictures into
# docs/images/. Later stages extend it to the whole graph and its accuracy table.
set -eo pipefail
cd "$VLC_WS"
ros2run vlc_stereo_camera render_demo_images
echo "demo: pictures written to docs/images/ (see README.md)"
