#!/usr/bin/env bash
# Download Debian/Ubuntu packages and unpack them into a folder, without installing them (no root):
# `apt-get download` + `dpkg-deb -x`. Idempotent: a package whose marker names the wanted version is
# skipped, so a second run is a fast no-op.
#
# Usage: scripts/fetch_debs.sh DEST PACKAGE=VERSION=[PATH] ...
#   VERSION empty: the archive's candidate (any version already unpacked counts as done).
#   PATH (a glob): extract only that part of the package, plus its copyright file.
set -euo pipefail

DEST="$1"; shift
mkdir -p "$DEST/root" "$DEST/markers"
missing=()
for entry in "$@"; do
  IFS='=' read -r pkg version subdir <<<"$entry"
  marker="$DEST/markers/$pkg"
  if [[ -f "$marker" && ( -z "$version" || "$(cat "$marker")" == "$version" ) ]]; then continue; fi
  missing+=("$entry")
done
if [[ ${#missing[@]} -eq 0 ]]; then
  echo "up to date in $DEST"
  exit 0
fi

if ! apt-cache show "${missing[0]%%=*}" >/dev/null 2>&1; then
  apt-get update -qq
fi
workdir="$(mktemp -d "$DEST/.download.XXXXXX")"
trap 'rm -rf "$workdir"' EXIT
for entry in "${missing[@]}"; do
  IFS='=' read -r pkg version subdir <<<"$entry"
  echo "fetching $pkg ${version:-(candidate)}"
  (cd "$workdir" && apt-get download -q -o APT::Sandbox::User="$(id -un)" "$pkg${version:+=$version}")
  deb="$(ls "$workdir"/"${pkg}"_*.deb)"
  if [[ -n "$subdir" ]]; then
    dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$DEST/root" --wildcards "$subdir" "./usr/share/doc/$pkg/copyright"
  else
    dpkg-deb -x "$deb" "$DEST/root"
  fi
  dpkg-deb -f "$deb" Version >"$DEST/markers/$pkg"
  rm -f "$deb"
done
echo "ready in $DEST"
