#!/usr/bin/env bash
# Pretrained detector weights that ship inside a registry package, pinned by version and hash:
# the CenterNet (MobileNetV3, COCO) TF.js graph of the npm package @vladmandic/human 3.3.6 (MIT
# package; upstream weights: github.com/610265158/mobilenetv3_centernet, licence not stated
# by the package). Only re-training the detector and its conversion test need it: the shipped
# fine-tuned checkpoint (src/detector_node/models/) runs without it.
#
# Usage: scripts/fetch_pretrained.sh DEST   (DEST: cache folder, e.g. .venv/pretrained)
# Fetches the tarball with `npm pack` (or takes PRETRAINED_TARBALL=FILE), checks its sha512,
# extracts models/centernet.{json,bin} and LICENSE into DEST/vladmandic-human-3.3.6/ and checks
# their sha256. A second run only re-checks the two files' sha256 (fast). Any missing or changed
# file: one line `[setup] error: ...` on stderr, exit 1.
set -euo pipefail

PKG="@vladmandic/human"
VERSION="3.3.6"
TARBALL_SHA512="${PRETRAINED_SHA512:-36be663dfab5810fae29e5d8e6e337163f14c6f179084876b3ab71339c114e1a9a5b4985f61ba8a0eb994ab4fc8611a1a348466972c5740c1f0ffdbeb5e0afe8}"
JSON_SHA256="bfb942eaacc5becf738d536663bc4580a0ae9e560722306e6d4dd7fe4a09de05"
BIN_SHA256="1b635a15009071f506f9f2b3519b31c072c534888989f30d269ffd44734ef7ef"

die() { printf '[setup] error: %s\n' "$*" >&2; exit 1; }
[ $# -eq 1 ] || die "usage: fetch_pretrained.sh DEST"
dest="$1/vladmandic-human-$VERSION"

files_ok() {
  [ -f "$dest/centernet.json" ] && [ -f "$dest/centernet.bin" ] &&
    [ "$(sha256sum "$dest/centernet.json" | cut -d' ' -f1)" = "$JSON_SHA256" ] &&
    [ "$(sha256sum "$dest/centernet.bin" | cut -d' ' -f1)" = "$BIN_SHA256" ]
}
files_ok && exit 0

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
if [ -n "${PRETRAINED_TARBALL:-}" ]; then
  [ -f "$PRETRAINED_TARBALL" ] || die "$PRETRAINED_TARBALL: pretrained package tarball not found"
  tgz="$PRETRAINED_TARBALL"
else
  command -v npm >/dev/null 2>&1 ||
    die "npm not found: needed once to fetch $PKG@$VERSION (pretrained detector weights)"
  (cd "$tmp" && npm pack --silent "$PKG@$VERSION" >/dev/null 2>"$tmp/npm.log") ||
    die "npm pack $PKG@$VERSION failed: $(tail -n 1 "$tmp/npm.log")"
  tgz="$tmp/vladmandic-human-$VERSION.tgz"
  [ -f "$tgz" ] || die "npm pack $PKG@$VERSION: tarball not produced"
fi
got=$(sha512sum "$tgz" | cut -d' ' -f1)
[ "$got" = "$TARBALL_SHA512" ] ||
  die "$tgz: sha512 $got differs from the pinned $PKG@$VERSION ($TARBALL_SHA512): package changed or wrong file"
tar -xzf "$tgz" -C "$tmp" package/models/centernet.json package/models/centernet.bin package/LICENSE \
  2>/dev/null || die "$tgz: models/centernet.{json,bin} missing from the package"
mkdir -p "$dest"
cp "$tmp/package/models/centernet.json" "$tmp/package/models/centernet.bin" "$tmp/package/LICENSE" "$dest/"
files_ok || die "$dest: extracted centernet.{json,bin} do not match their pinned sha256"
printf '[setup] pretrained detector weights: %s@%s in %s\n' "$PKG" "$VERSION" "$dest" >&2
