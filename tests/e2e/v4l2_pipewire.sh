#!/usr/bin/env bash
# The real V4L2 backend through PipeWire's V4L2 compatibility layer (libpw-v4l2.so, preloaded):
# a private session bus, PipeWire and WirePlumber started here, a GStreamer videotestsrc published
# as a camera node (pipewiresink mode=provide, media.class=Video/Source), and `commonlight record
# --camera v4l2:/dev/video0` streaming YUYV and MJPEG from it. `commonlight cameras` must list it.
#
# Runs in a private network namespace with only loopback (commonlight cameras may run Aravis
# discovery, which broadcasts); PipeWire and D-Bus talk over unix sockets in a private
# XDG_RUNTIME_DIR. Skips (77) when a daemon or tool is missing or cannot start.
set -euo pipefail

source "$(dirname "$0")/netns.sh"
source "$(dirname "$0")/lib.sh"

PW_V4L2=""
for candidate in /usr/lib/x86_64-linux-gnu/pipewire-0.3/v4l2/libpw-v4l2.so /usr/lib/*/pipewire-0.3/v4l2/libpw-v4l2.so; do
    if [[ -f $candidate ]]; then PW_V4L2=$candidate; break; fi
done
[[ -n $PW_V4L2 ]] || skip "libpw-v4l2.so not found (install pipewire-v4l2)"
for tool in dbus-daemon pipewire wireplumber pw-cli gst-launch-1.0 gst-inspect-1.0; do
    command -v "$tool" >/dev/null || skip "$tool not found (scripts/install-deps)"
done
gst-inspect-1.0 pipewiresink >/dev/null 2>&1 || skip "GStreamer's pipewiresink not found (gstreamer1.0-pipewire)"
"$COMMONLIGHT" cameras --json | grep -q '"scheme": "v4l2"' || skip "this build has no V4L2 backend"

# Every daemon this test starts, killed on exit (by pid).
PIDS=()
cleanup() {
    local pid
    for pid in "${PIDS[@]}"; do kill "$pid" 2>/dev/null || true; done
    for pid in "${PIDS[@]}"; do wait "$pid" 2>/dev/null || true; done
    rm -rf "$TMP"
}
trap cleanup EXIT

export XDG_RUNTIME_DIR="$TMP/run" XDG_CONFIG_HOME="$TMP/config" XDG_STATE_HOME="$TMP/state" XDG_DATA_HOME="$TMP/data"
mkdir -m 700 "$XDG_RUNTIME_DIR"
mkdir -p "$XDG_CONFIG_HOME" "$XDG_STATE_HOME" "$XDG_DATA_HOME"
export DBUS_SESSION_BUS_ADDRESS="unix:path=$XDG_RUNTIME_DIR/bus"
export PIPEWIRE_DEBUG=1 WIREPLUMBER_DEBUG=1
unset PIPEWIRE_REMOTE PIPEWIRE_V4L2_TARGET DISPLAY WAYLAND_DISPLAY || true

# wait_for SECONDS command...: retries the command every 0.1 s.
wait_for() {
    local tries=$(( $1 * 10 )); shift
    for (( i = 0; i < tries; i++ )); do
        if "$@" >/dev/null 2>&1; then return 0; fi
        sleep 0.1
    done
    return 1
}

dbus-daemon --session --address="$DBUS_SESSION_BUS_ADDRESS" --nofork --nopidfile >"$TMP/dbus.log" 2>&1 &
PIDS+=($!)
wait_for 10 test -S "$XDG_RUNTIME_DIR/bus" || { cat "$TMP/dbus.log"; skip "the session bus did not start"; }
pipewire >"$TMP/pipewire.log" 2>&1 &
PIDS+=($!)
wait_for 10 test -S "$XDG_RUNTIME_DIR/pipewire-0" || { cat "$TMP/pipewire.log"; skip "pipewire did not start"; }
wait_for 10 pw-cli info 0 || { cat "$TMP/pipewire.log"; skip "pipewire does not answer"; }
wireplumber >"$TMP/wireplumber.log" 2>&1 &
WP=$!
PIDS+=($WP)
wait_for 10 bash -c 'pw-cli ls Client | grep -qi wireplumber' || { cat "$TMP/wireplumber.log"; skip "wireplumber did not start"; }

# start_source NAME CAPS...: a live test pattern published as a camera node named NAME.
SOURCE=""
start_source() {
    local name=$1; shift
    gst-launch-1.0 -q videotestsrc is-live=true pattern=ball ! "$@" ! \
        pipewiresink mode=provide client-name="$name" \
        stream-properties="props,media.class=Video/Source,media.role=Camera,node.description=$name" \
        >"$TMP/gst-$name.log" 2>&1 &
    SOURCE=$!
    PIDS+=($SOURCE)
    wait_for 15 bash -c "pw-cli ls Node | grep -q 'node.name = \"$name\"'" ||
        { cat "$TMP/gst-$name.log"; fail "the GStreamer source $name did not appear as a PipeWire node"; }
}
stop_source() {
    kill "$SOURCE"
    wait "$SOURCE" 2>/dev/null || true
}

preloaded() { LD_PRELOAD="$PW_V4L2${LD_PRELOAD:+ $LD_PRELOAD}" "$@"; }
# Under ASan (verify_asan_link_order=0 lets the preload start) `commonlight cameras` with
# libpw-v4l2 preloaded hangs (seen with PipeWire 0.3.65, not understood yet): the sanitizer build
# covers the backend with the fake device instead (tests/hal/v4l2_*).
if [[ -n ${ASAN_OPTIONS:-} ]]; then
    skip "libpw-v4l2.so preloaded into an ASan build hangs; the V4L2 backend is checked under ASan by tests/hal/v4l2_*"
fi

# check_sequence SEQ FORMAT EXT: 30 frames, the format and size, increasing sequence and time.
check_sequence() {
    local seq=$1 format=$2 ext=$3
    [[ $(rows "$seq/cam0/data.csv") == 30 ]] || fail "$seq: expected 30 frames in data.csv"
    [[ $(ls "$seq/cam0/data" | grep -c "\\.$ext\$") == 30 ]] || fail "$seq: expected 30 .$ext files"
    expect_text "pixel_format: $format" "$seq/cam0/sensor.yaml"
    expect_text "resolution: [640, 480]" "$seq/cam0/sensor.yaml"
    python3 - "$seq" "$ext" <<'PY' || fail "$seq: bad frames or metadata"
import os, sys
seq, ext = sys.argv[1], sys.argv[2]
rows = [l.strip().split(",") for l in open(f"{seq}/cam0/meta.csv") if not l.startswith("#")]
stamps = [int(r[0]) for r in rows]
sequences = [int(r[1]) for r in rows]
assert all(b > a for a, b in zip(stamps, stamps[1:])), "timestamps not increasing"
assert all(b > a for a, b in zip(sequences, sequences[1:])), "sequence numbers not increasing"
assert all(r[4] == "ok" for r in rows), "a frame is not ok"
for name in os.listdir(f"{seq}/cam0/data"):
    data = open(f"{seq}/cam0/data/{name}", "rb").read()
    if ext == "jpg":
        assert data[:2] == b"\xff\xd8" and data.rstrip(b"\0")[-2:] == b"\xff\xd9", f"{name}: not a whole JPEG"
    else:
        assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{name}: not a PNG"
    assert len(data) > 1000, f"{name}: too small to hold the test pattern"
PY
}

# --- YUYV ---
start_source yuyv-cam video/x-raw,format=YUY2,width=640,height=480,framerate=30/1
expect_exit 0 preloaded "$COMMONLIGHT" cameras
expect_text "v4l2:/dev/video0  yuyv-cam (v4l2)" "$TMP/out"
expect_text "yuyv 640x480" "$TMP/out"
expect_exit 0 preloaded "$COMMONLIGHT" cameras --json
expect_text '"uri": "v4l2:/dev/video0"' "$TMP/out"
expect_exit 0 preloaded "$COMMONLIGHT" record --camera "v4l2:/dev/video0?format=yuyv" --out "$TMP/yuyv" --frames 30
expect_text "recorded 30 frames" "$TMP/out"
check_sequence "$TMP/yuyv" yuyv png
# A format the device does not offer: a usage error listing what it offers.
expect_exit 2 preloaded "$COMMONLIGHT" record --camera "v4l2:/dev/video0?format=nv12" --out "$TMP/nv12" --frames 3
expect_text "v4l2:/dev/video0: cannot stream nv12" "$TMP/err"
expect_text "yuyv 640x480" "$TMP/err"
stop_source

# The source goes away mid-stream: the recording ends with a device error naming the camera, and
# the frames recorded so far form a closed, readable sequence. (A new source: GStreamer's
# pipewiresink in mode=provide, as of PipeWire 0.3.65, stays suspended after its first consumer
# leaves, so a second recording from the same source gets no frame.)
start_source cut-cam video/x-raw,format=YUY2,width=640,height=480,framerate=30/1
preloaded "$COMMONLIGHT" record --camera "v4l2:/dev/video0?format=yuyv&timeout_ms=3000" --out "$TMP/cut" \
    --frames 100000 >"$TMP/cut.out" 2>"$TMP/cut.err" &
RECORDER=$!
wait_for 30 bash -c "[[ -f '$TMP/cut/cam0/data.csv' && \$(grep -vc '^#' '$TMP/cut/cam0/data.csv') -ge 10 ]]" ||
    { kill "$RECORDER" 2>/dev/null || true; cat "$TMP/cut.out" "$TMP/cut.err"; fail "the recording did not start"; }
stop_source
set +e
wait "$RECORDER"
code=$?
set -e
[[ $code == 4 ]] || { cat "$TMP/cut.out" "$TMP/cut.err"; fail "expected exit 4 (device error) after the source went away, got $code"; }
expect_text "v4l2:/dev/video0" "$TMP/cut.err"
echo "after the cut: $(grep error "$TMP/cut.err")"
[[ $(rows "$TMP/cut/cam0/data.csv") -ge 10 ]] || fail "the frames before the cut were not kept"
[[ $(rows "$TMP/cut/cam0/data.csv") == $(rows "$TMP/cut/cam0/meta.csv") ]] || fail "data.csv and meta.csv disagree"

# --- MJPEG ---
start_source mjpeg-cam video/x-raw,width=640,height=480,framerate=30/1 ! jpegenc ! image/jpeg,width=640,height=480,framerate=30/1
expect_exit 0 preloaded "$COMMONLIGHT" cameras
expect_text "v4l2:/dev/video0  mjpeg-cam (v4l2)" "$TMP/out"
expect_text "mjpeg 640x480" "$TMP/out"
expect_exit 0 preloaded "$COMMONLIGHT" record --camera "v4l2:/dev/video0?format=mjpeg" --out "$TMP/mjpeg" --frames 30
expect_text "recorded 30 frames" "$TMP/out"
check_sequence "$TMP/mjpeg" mjpeg jpg
stop_source
echo PASS
