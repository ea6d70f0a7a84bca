#!/usr/bin/env bash
# Fetch what the microphone path needs from the distro archive, without root (scripts/fetch_debs.sh):
# PortAudio (libportaudio2, loaded by `sounddevice`) and the JACK client library it links against,
# and ALSA's development files (headers for the virtual microphone, m2h_ros/io/virtual_mic.py).
# Any version the archive offers will do; a machine with libportaudio2 installed uses its own.
#
# Usage: scripts/fetch_audio_libs.sh [DEST]   (default: ${M2H_DATA_DIR:-~/.cache/m2h_ros}/audio_libs,
#   the folder m2h_ros.io.portaudio looks in)
set -euo pipefail
DEST="${1:-${M2H_DATA_DIR:-$HOME/.cache/m2h_ros}/audio_libs}"
echo "audio libraries: $("$(dirname "${BASH_SOURCE[0]}")/fetch_debs.sh" "$DEST" \
  libportaudio2== libjack-jackd2-0== libasound2-dev== | tail -n 1)"
