#!/bin/sh
# Installs the one system library the default build needs: HDF5, for
# `causalcity export vcdn` (cargo feature `hdf5`). Does nothing when
# pkg-config already finds it. Build without it: `make FEATURES= ...`.
set -eu
if pkg-config --exists hdf5 2>/dev/null; then
  exit 0
fi
echo "installing the HDF5 library (for V-CDN export)..." >&2
if command -v apt-get >/dev/null 2>&1; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null 2>&1 || {
      echo "error: need root or sudo to run apt-get install libhdf5-dev pkg-config; or build without V-CDN export: make FEATURES= <target>" >&2
      exit 1
    }
    SUDO="sudo"
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends libhdf5-dev pkg-config >/dev/null
elif command -v brew >/dev/null 2>&1; then
  brew install hdf5 pkg-config
else
  echo "error: cannot install HDF5 here: install your system's HDF5 development package (libhdf5-dev, hdf5-devel or hdf5)" >&2
  echo "       and pkg-config, or build without V-CDN export: make FEATURES= <target>" >&2
  exit 1
fi
pkg-config --exists hdf5 || { echo "error: HDF5 installed but pkg-config cannot find hdf5.pc" >&2; exit 1; }
