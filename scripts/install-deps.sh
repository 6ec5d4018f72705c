#!/usr/bin/env bash
# Installs, from Debian's packages, whatever partloc needs to build and test and is not yet on the machine.
set -euo pipefail
pkgs=(cmake g++ make pkg-config
      libopen3d-dev libembree-dev libeigen3-dev libyaml-cpp-dev nlohmann-json3-dev libcli11-dev
      libtbb-dev libssl-dev libgtest-dev libgmock-dev libbenchmark-dev clang-format
      libglpk-dev libocct-data-exchange-dev libocct-modeling-algorithms-dev libjs-three chromium)
# GLPK: the placement's linear programmes; Open CASCADE: STEP models; three.js and Chromium: the report's
# 3D view and its browser test.
[[ "${PARTLOC_WITH_PCL:-0}" == 1 ]] && pkgs+=(libpcl-dev)
# make fuzz: clang with its libFuzzer and sanitizer runtimes.
[[ "${PARTLOC_WITH_FUZZ:-0}" == 1 ]] && pkgs+=(clang libclang-rt-14-dev)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
((${#missing[@]})) || exit 0
echo "installing: ${missing[*]}"
SUDO=""
[[ $(id -u) -ne 0 ]] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
