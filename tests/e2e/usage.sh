#!/usr/bin/env bash
# Usage errors exit 2 with a message; --help works everywhere.
source "$(dirname "$0")/lib.sh"

expect_exit 0 "$COMMONLIGHT" --help
expect_text "cameras" "$TMP/out"
for sub in cameras record play calibrate; do
    expect_exit 0 "$COMMONLIGHT" "$sub" --help
    expect_text "Usage" "$TMP/out"
done
expect_exit 2 "$COMMONLIGHT"
expect_exit 2 "$COMMONLIGHT" frobnicate
expect_exit 2 "$COMMONLIGHT" play
expect_exit 2 "$COMMONLIGHT" record --out "$TMP/x"
expect_exit 2 "$COMMONLIGHT" record --camera "nope:/dev/video0" --out "$TMP/x"
expect_text "unknown scheme 'nope'" "$TMP/err"
expect_text "replay:" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" record --camera "replay:$SAMPLE?speeed=2" --out "$TMP/x"
expect_text "unknown option 'speeed'" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" record --camera "replay:$SAMPLE?rate=sometimes" --out "$TMP/x"
expect_text "rate" "$TMP/err"
expect_exit 2 "$COMMONLIGHT" record --camera "replay:$SAMPLE?width=320" --out "$TMP/x"
expect_text "the device offers" "$TMP/err"
[[ ! -e "$TMP/x" ]] || fail "a usage error must not create the output folder"
# Enumeration runs Aravis discovery, a broadcast on every interface: tests run it only in a
# private network namespace (loopback only).
if unshare -n true 2>/dev/null; then
    expect_exit 0 isolated "$COMMONLIGHT" cameras --json
    python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); assert "cameras" in d and any(b["scheme"]=="replay" for b in d["backends"])' "$TMP/out"
else
    echo "note: unshare -n not permitted; commonlight cameras not run (it would broadcast)"
fi
echo PASS
