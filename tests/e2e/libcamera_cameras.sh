#!/usr/bin/env bash
# `commonlight cameras` with the libcamera backend built in: it lists the backend, enumerates
# without an error, and prints nothing on stderr (libcamera's INFO/WARN logging is quieted
# unless LIBCAMERA_LOG_LEVELS is set). A camera that is not there is exit 3 naming it.
# Runs in a private network namespace: a build with Aravis would broadcast while enumerating.
source "$(dirname "$0")/lib.sh"

if ! unshare -n true 2>/dev/null; then
    skip "needs unshare -n (a private network namespace) to enumerate cameras"
fi

expect_exit 0 isolated env -u LIBCAMERA_LOG_LEVELS "$COMMONLIGHT" cameras --json
if python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); sys.exit(0 if any(b["scheme"]=="libcamera" for b in d["left_out"]) else 1)' "$TMP/out"; then
    skip "this build has no libcamera backend"
fi
python3 - "$TMP/out" <<'PY' || fail "commonlight cameras --json: libcamera backend missing or failing"
import json, sys
d = json.load(open(sys.argv[1]))
assert any(b["scheme"] == "libcamera" and b["enumerates"] for b in d["backends"]), d["backends"]
assert not [e for e in d["errors"] if "libcamera" in json.dumps(e)], d["errors"]
for c in d["cameras"]:
    if c["backend"] == "libcamera":
        assert c["uri"].startswith("libcamera:"), c
PY
[[ ! -s "$TMP/err" ]] || { cat "$TMP/err"; fail "commonlight cameras wrote to stderr (libcamera logging?)"; }

# The user's LIBCAMERA_LOG_LEVELS still wins.
expect_exit 0 isolated env LIBCAMERA_LOG_LEVELS='*:INFO' "$COMMONLIGHT" cameras
expect_text "libcamera v" "$TMP/err"

expect_exit 3 isolated "$COMMONLIGHT" record --camera "libcamera:no-such-camera" --out "$TMP/seq" --frames 1
expect_text "no libcamera camera 'no-such-camera'" "$TMP/err"
expect_exit 2 isolated "$COMMONLIGHT" record --camera "libcamera:0?role=preview" --out "$TMP/seq" --frames 1
expect_text "role must be viewfinder, video, still or raw" "$TMP/err"
echo "ok"
