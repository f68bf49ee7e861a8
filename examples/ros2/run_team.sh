#!/usr/bin/env bash
# The same team without ROS's launch: one line per robot (each on its own robot in practice).
# Stop with Ctrl-C (each node publishes its last diagnostics and leaves the team).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
for r in 0 1 2; do
  swarmloc ros --ros-args --params-file "$here/team.yaml" -r "__ns:=/robot$r" \
    -r odom:=wheel/odom -r detections:=camera/detections &
done
wait
