# Helpers for the end-to-end tests of the commonlight command line. Source it first.
set -euo pipefail
: "${COMMONLIGHT:?set by CTest: path of the commonlight binary}"
SRC=${COMMONLIGHT_SOURCE_DIR:?set by CTest}
SAMPLE="$SRC/data/sample"
TMP=$(mktemp -d /tmp/commonlight-e2e-XXXXXX)
trap 'rm -rf "$TMP"' EXIT

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
