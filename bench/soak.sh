#!/usr/bin/env bash
# Soak: clipmapd serving the hash texture for a long time while readers in Rust, C and Python
# check every texel they read, one Rust reader flying the centre fast (jumps, reversals); then a
# second phase where the service is killed with SIGKILL and restarted repeatedly under Rust
# readers that follow it. Prints each reader's counts and the totals; exits 1 on any mismatch.
#
# Usage: bench/soak.sh [--seconds S] [--restarts N] [--clip C] [--dir DIR]
#   --seconds S    length of each phase (default 600)
#   --restarts N   SIGKILL + restart cycles in the second phase, spread over S (default 20; 0 skips it)
#   --clip C       clip size (default 1024)
#   --dir DIR      directory for the mapping, socket and logs (default: a new temporary one)
set -euo pipefail

SECONDS_PER_PHASE=600
RESTARTS=20
CLIP=1024
DIR=""
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
while [ $# -gt 0 ]; do
    case "$1" in
        --seconds) SECONDS_PER_PHASE="$2"; shift 2 ;;
        --restarts) RESTARTS="$2"; shift 2 ;;
        --clip) CLIP="$2"; shift 2 ;;
        --dir) DIR="$2"; shift 2 ;;
        -h | --help) sed -n '2,12p' "$0"; exit 0 ;;
        *) echo "soak.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
[ -n "$DIR" ] || DIR="$(mktemp -d)"
mkdir -p "$DIR"
cd "$ROOT"
cargo build --release --bin clipmapd --bin clipmap-read >&2
cc -O2 -I include clients/c/reader.c -o "$DIR/c-reader"
D=target/release
NAME=soak
MAP="$DIR/clipmap-$NAME.map"
SVC=()

start_service() {
    "$D/clipmapd" --source hash --size 1048576 --clip "$CLIP" --tile 256 --name "$NAME" \
        --shm-dir "$DIR" --socket "$DIR/$NAME.sock" >> "$DIR/service.log" 2>&1 &
    SVC=("$!")
    for _ in $(seq 1 300); do [ -e "$MAP" ] && return 0; sleep 0.1; done
    echo "soak.sh: the service did not start; see $DIR/service.log" >&2
    exit 2
}
cleanup() { [ ${#SVC[@]} -gt 0 ] && kill "${SVC[0]}" 2> /dev/null || true; }
trap cleanup EXIT

total_pass=0
total_fail=0
add_counts() { # FILE LABEL
    local line
    line="$(grep -E '^[0-9]+ passed, [0-9]+ failed' "$1" | tail -1 || true)"
    if [ -z "$line" ]; then
        echo "soak.sh: $2 printed no counts (see $1)" >&2
        total_fail=$((total_fail + 1))
        return
    fi
    printf '  %-36s %s\n' "$2" "$line"
    total_pass=$((total_pass + $(echo "$line" | cut -d' ' -f1)))
    total_fail=$((total_fail + $(echo "$line" | cut -d' ' -f3)))
}

S="$SECONDS_PER_PHASE"
MANY=1000000000000
echo "phase 1: $S s, clip $CLIP, readers in Rust (one driving), C and Python"
start_service
"$D/clipmap-read" --name "$NAME" --shm-dir "$DIR" --drive --reads "$MANY" --seconds "$S" --seed 1 > "$DIR/r1.out" 2>&1 &
P1=$!
"$D/clipmap-read" --name "$NAME" --shm-dir "$DIR" --reads "$MANY" --seconds "$S" --seed 2 > "$DIR/r2.out" 2>&1 &
P2=$!
"$DIR/c-reader" "$MAP" "$MANY" 3 "$S" > "$DIR/c.out" 2>&1 &
P3=$!
python3 clients/python/clipmap_shm.py "$MAP" "$MANY" 4 "$S" > "$DIR/py.out" 2>&1 &
P4=$!
wait "$P1" "$P2" "$P3" "$P4" || true
add_counts "$DIR/r1.out" "Rust reader, driving the flight"
add_counts "$DIR/r2.out" "Rust reader"
add_counts "$DIR/c.out" "C reader"
add_counts "$DIR/py.out" "Python reader"
kill "${SVC[0]}" 2> /dev/null || true
wait "${SVC[0]}" 2> /dev/null || true

if [ "$RESTARTS" -gt 0 ]; then
    echo "phase 2: $S s, SIGKILL and restart $RESTARTS times under two following Rust readers"
    start_service
    "$D/clipmap-read" --name "$NAME" --shm-dir "$DIR" --drive --follow --reads "$MANY" --seconds "$S" --seed 5 > "$DIR/f1.out" 2>&1 &
    F1=$!
    "$D/clipmap-read" --name "$NAME" --shm-dir "$DIR" --follow --reads "$MANY" --seconds "$S" --seed 6 > "$DIR/f2.out" 2>&1 &
    F2=$!
    gap=$(awk -v s="$S" -v n="$RESTARTS" 'BEGIN { printf "%.2f", s / (n + 1) }')
    for _ in $(seq 1 "$RESTARTS"); do
        sleep "$gap"
        kill -9 "${SVC[0]}" 2> /dev/null || true
        wait "${SVC[0]}" 2> /dev/null || true
        sleep 0.5
        start_service
    done
    wait "$F1" "$F2" || true
    add_counts "$DIR/f1.out" "Rust follower, driving"
    add_counts "$DIR/f2.out" "Rust follower"
    for f in f1 f2; do
        grep -o '"reattached":[0-9]*' "$DIR/$f.out" | sed "s/^/  $f /" || true
    done
fi
echo "total: $total_pass passed, $total_fail failed (logs in $DIR)"
[ "$total_fail" = 0 ]
