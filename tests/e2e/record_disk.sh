#!/usr/bin/env bash
# Recording into a read-only or a full file system: a clear error, exit 3, and the frames
# already written stay valid. Needs a private mount namespace (unshare -m) to mount tmpfs.
source "$(dirname "$0")/lib.sh"

if [[ $(id -u) != 0 ]] || ! unshare -m true 2>/dev/null; then
    skip "needs root and unshare -m to mount a small tmpfs"
fi
mkdir -p "$TMP/mnt"

# Read-only: fails at once, naming the folder.
expect_exit 3 unshare -m sh -c "mount -t tmpfs -o ro,size=1m tmpfs '$TMP/mnt' && exec '$COMMONLIGHT' record --camera 'replay:$SAMPLE?rate=max' --out '$TMP/mnt/seq' --sync"
expect_text "$TMP/mnt/seq" "$TMP/err"
expect_text "Read-only file system" "$TMP/err"

# Full: 1 MiB holds only part of the sample. The error names the file and the reason,
# and the frames before it replay. The test copies the partial sequence out of the namespace.
expect_exit 3 unshare -m sh -c "mount -t tmpfs -o size=1m tmpfs '$TMP/mnt' && '$COMMONLIGHT' record --camera 'replay:$SAMPLE?rate=max' --out '$TMP/mnt/seq' --sync; rc=\$?; cp -r '$TMP/mnt/seq' '$TMP/partial'; exit \$rc"
expect_text "No space left on device" "$TMP/err"
n=$(rows "$TMP/partial/cam0/data.csv")
[[ $n -ge 3 && $n -lt $SAMPLE_FRAMES ]] || fail "expected a partial sequence, got $n frames"
expect_exit 0 "$COMMONLIGHT" play "$TMP/partial" --sync
expect_text "played $n of $n frames" "$TMP/out"
expect_text "(0 corrupt)" "$TMP/out"
echo PASS
