#!/usr/bin/env bash
# Debian packages for headless OpenGL (pyrender through EGL on Mesa's llvmpipe), and chromium
# (the report's test loads report.html in a real headless browser).
# Installs only what is missing; uses sudo when not root.
set -euo pipefail
pkgs=(libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libglvnd0 chromium)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "installing Debian packages: ${missing[*]}"
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
