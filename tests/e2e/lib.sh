# Helpers for the end-to-end tests of the commonlight command line. Source it first.
set -euo pipefail
: "${COMMONLIGHT:?set by CTest: path of the commonlight binary}"
SRC=${COMMONLIGHT_SOURCE_DIR:?set by CTest}
SAMPLE="$SRC/data/sample"
TMP=$(mktemp -d /tmp/commonlight-e2e-XXXXXX)
SERVER_PID=  # a background server a test started (start_serve_gige); killed on exit
BG_PIDS=()   # other background processes a test started (live in a window); killed on exit
trap '[[ -n $SERVER_PID ]] && kill -9 "$SERVER_PID" 2>/dev/null; for p in "${BG_PIDS[@]}"; do kill -9 "$p" 2>/dev/null || true; done; [[ -n ${KEEP_TMP:-} ]] || rm -rf "$TMP"' EXIT

fail() { echo "FAIL: $*" >&2; exit 1; }
skip() { echo "SKIP: $*" >&2; exit 77; }

# expect_exit CODE command...: runs it, keeps stdout/stderr in $TMP/out, $TMP/err.
expect_exit() {
    local want=$1; shift
    set +e
    "$@" >"$TMP/out" 2>"$TMP/err"
    local got=$?
    set -e
    if [[ $got != "$want" ]]; then
        echo "--- stdout"; cat "$TMP/out"; echo "--- stderr"; cat "$TMP/err"
        fail "expected exit $want, got $got: $*"
    fi
}

# expect_text TEXT FILE: FILE contains TEXT (fixed string).
expect_text() {
    grep -qF -- "$1" "$2" || { echo "--- $2"; cat "$2"; fail "expected '$1' in $2"; }
}

# json_get FILE KEY: a top-level number from a JSON file.
json_get() {
    python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])' "$1" "$2"
}

# A writable copy of the bundled sample.
copy_sample() {
    cp -r "$SAMPLE" "$1"
}

# frame_file SEQ N: path of the Nth frame (0-based) listed in data.csv.
frame_file() {
    local name
    name=$(grep -v '^#' "$1/cam0/data.csv" | sed -n "$(( $2 + 1 ))p" | cut -d, -f2)
    echo "$1/cam0/data/$name"
}

rows() { grep -vc '^#' "$1"; }

# Frames in the bundled sample.
SAMPLE_FRAMES=$(rows "$SAMPLE/cam0/data.csv")

# isolated COMMAND...: runs it in a new private network namespace with only loopback (for
# commands that may broadcast, such as Aravis discovery in `commonlight cameras`).
isolated() { unshare -n sh -c 'ip link set lo up 2>/dev/null; exec "$@"' sh "$@"; }

# wait_for_rows SEQ N: waits (up to 30 s) until SEQ/cam0/data.csv lists at least N frames.
wait_for_rows() {
    for _ in $(seq 1 600); do
        [[ -f "$1/cam0/data.csv" && $(rows "$1/cam0/data.csv") -ge $2 ]] && return 0
        sleep 0.05
    done
    fail "$1 did not reach $2 frames"
}

# start_serve_gige ARGS...: `commonlight serve-gige ARGS` in the background (SERVER_PID), waiting
# until it serves. Only inside a private network namespace (netns.sh).
start_serve_gige() {
    # Emptied first: the background shell truncates it only once it runs, and the wait below must
    # not read an earlier server's "serving" line.
    : >"$TMP/server.out"
    "$COMMONLIGHT" serve-gige "$@" >"$TMP/server.out" 2>"$TMP/server.err" &
    SERVER_PID=$!
    for _ in $(seq 1 200); do
        grep -q "^serving " "$TMP/server.out" 2>/dev/null && return 0
        kill -0 "$SERVER_PID" 2>/dev/null || { cat "$TMP/server.err"; fail "serve-gige exited: $*"; }
        sleep 0.05
    done
    fail "serve-gige did not start: $*"
}

# find_window PID: prints the id of the window of process PID titled commonlight..., waiting up to
# 30 s. By PID, never by title alone: other GL tests may have windows on the same display.
find_window() {
    local wid
    for _ in $(seq 1 150); do
        wid=$(xdotool search --all --pid "$1" --name '^commonlight' 2>/dev/null | head -1 || true)
        [[ -n $wid ]] && { echo "$wid"; return 0; }
        kill -0 "$1" 2>/dev/null || return 1
        sleep 0.2
    done
    return 1
}

# wait_for_log TEXT FILE [SECONDS]: waits until FILE contains TEXT (fixed string; default 90 s).
wait_for_log() {
    local limit=${3:-90}
    for _ in $(seq 1 $((limit * 10))); do
        grep -qF -- "$1" "$2" 2>/dev/null && return 0
        sleep 0.1
    done
    echo "--- $2"; cat "$2"
    fail "waited $limit s for '$1' in $2"
}

# ctrl_c_live PID: Ctrl-C to a running `live` (started with its stderr in $TMP/live.err); it
# must end with exit 130 (its metrics and recordings written).
ctrl_c_live() {
    kill -INT "$1"
    local code
    set +e
    wait "$1"
    code=$?
    set -e
    [[ $code == 130 ]] || { cat "$TMP/live.err"; fail "live ended with $code after Ctrl-C (expected 130)"; }
}

# count_of NAME COUNTS: the count named NAME in pngcheck.py's output COUNTS.
count_of() { awk -v n="$1" '$1 == n {print $2}' <<<"$2"; }

# wait_for_title WID PATTERN [SECONDS]: waits until window WID's title contains PATTERN (a bash
# glob; default 90 s). live's title says "| tracked |" once a tracked frame has been composited
# and shown, and "lighting v1" (and on) once it was drawn with a lighting snapshot.
wait_for_title() {
    local limit=${3:-90}
    for _ in $(seq 1 $((limit * 10))); do
        # shellcheck disable=SC2053
        [[ $(xdotool getwindowname "$1" 2>/dev/null || true) == *$2* ]] && return 0
        sleep 0.1
    done
    fail "waited $limit s for '$2' in the title of window $1 ($(xdotool getwindowname "$1" 2>/dev/null || true))"
}
