#!/usr/bin/env bash
# Builds tinbuild_processing.zip, the plugin as QGIS's "Install from ZIP" takes it (Plugins > Manage and
# Install Plugins > Install from ZIP): one top folder tinbuild_processing/ holding the plugin's files, no
# caches.  Writes into OUTDIR (created when missing): outside the checkout, or a git-ignored build folder.
#
#   bash share/qgis/make-zip.sh OUTDIR        # -> OUTDIR/tinbuild_processing.zip
set -euo pipefail
if [ $# -ne 1 ]; then
  echo "usage: $0 OUTDIR" >&2
  exit 2
fi
here="$(cd "$(dirname "$0")" && pwd)"
outdir="$(realpath -m "$1")"
out="$outdir/tinbuild_processing.zip"
repo="$(cd "$here/../.." && pwd)"
case "$outdir/" in
  "$repo"/*)   # inside the checkout: only in a folder git ignores (a build tree)
    if ! git -C "$repo" check-ignore -q "$outdir/tinbuild_processing.zip" 2>/dev/null; then
      echo "$0: $1 is inside the repository and not ignored by git; choose a build folder or one outside it" >&2
      exit 2
    fi ;;
esac
mkdir -p "$outdir"
python3 - "$here" "$out" <<'PY'
import os, sys, zipfile
src, out = sys.argv[1], sys.argv[2]
tmp = out + '.tmp'
with zipfile.ZipFile(tmp, 'w', zipfile.ZIP_DEFLATED) as z:
    root = os.path.join(src, 'tinbuild_processing')
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d != '__pycache__')
        for name in sorted(files):
            if name.endswith(('.pyc', '.pyo')):
                continue
            path = os.path.join(folder, name)
            z.write(path, os.path.relpath(path, src))
os.replace(tmp, out)
print(out)
PY
