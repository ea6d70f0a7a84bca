#!/usr/bin/env bash
# Fetch the Debian packages the sound library is built from, without installing them system-wide:
# scripts/fetch_debs.sh (`apt-get download` + `dpkg-deb -x`) into a cache folder; a second run is a fast no-op.
#
# Usage: scripts/fetch_sound_sources.sh [DEST]
#   DEST defaults to $M2H_SOUND_SOURCES, else ${M2H_DATA_DIR:-~/.cache/m2h_ros}/sound_sources
#   (the same default as m2h_ros.core.sounds.sources.sources_dir()).
set -euo pipefail

DEST="${1:-${M2H_SOUND_SOURCES:-${M2H_DATA_DIR:-$HOME/.cache/m2h_ros}/sound_sources}}"

# package=version (pinned: the manifest records them; a new version is a new library).
# A path (glob) after the second '=' extracts only that part and the copyright file (megaglest-data is
# a 242 MB download, of which only the tileset sounds are kept).
PACKAGES=(
  "asterisk-core-sounds-en-g722=1.6.1-1="
  "asterisk-core-sounds-es-g722=1.6.1-1="
  "asterisk-core-sounds-fr-g722=1.6.1-1="
  "asterisk-core-sounds-it-g722=1.6.1-1="
  "asterisk-core-sounds-ru-g722=1.6.1-1="
  "asterisk-moh-opsound-g722=2.03-1.1="
  "timgm6mb-soundfont=1.3-5="
  "megaglest-data=3.13.0-3=./usr/share/games/megaglest/tilesets/*/sounds"
  "lincity-ng-data=2.9~git20150314-5=./usr/share/games/lincity-ng/sounds"
  "libmysofa1=1.3.1~dfsg0-1=./usr/share/libmysofa/MIT_KEMAR_normal_pinna.sofa"
)

echo "sound sources: $("$(dirname "${BASH_SOURCE[0]}")/fetch_debs.sh" "$DEST" "${PACKAGES[@]}" | tail -n 1)"
