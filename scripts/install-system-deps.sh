#!/usr/bin/env bash
# Install the Debian packages the tests need (real ROS 1, Chromium for the web station's
# browser tests, PostgreSQL for the shared station database) when they are missing.
# Runs as root in CI; elsewhere it uses sudo if it can and otherwise says what is missing.
set -euo pipefail
ros_pkgs=(ros-core python3-rospy python3-std-msgs python3-sensor-msgs python3-diagnostic-msgs
          ros-diagnostic-msgs python3-rosbag topic-tools chromium postgresql)
missing=()
for p in "${ros_pkgs[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
    echo "system-deps: all present"
    exit 0
fi
if [ "$(id -u)" -eq 0 ]; then sudo=""; elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo="sudo"; else
    echo "system-deps: missing ${missing[*]}; run as root: apt-get install -y --no-install-recommends ${missing[*]}" >&2
    exit 1
fi
echo "system-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "system-deps: done"
