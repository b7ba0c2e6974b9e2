#!/usr/bin/env bash
# Attack: replays the hostile-input classes of docs/RELIABILITY.md against the built binaries,
# each attempt bounded by a timeout, and prints one table row per attack: class, attack, exit
# status, seconds, the first line of what the tool said, and the verdict (ok when the outcome is
# the promised one: the expected exit status, no hang, the victim file untouched, the running
# service still answering).
#
# Usage: bench/attack.sh [--bin DIR] [--dir DIR] [--no-build]
#   --bin DIR    directory of the binaries (default target/release, built first)
#   --dir DIR    scratch directory (default: a new temporary one)
#   --no-build   do not run cargo build first
# Exits 1 when some attack did not end as promised.
set -uo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BIN="$ROOT/target/release"
DIR=""
BUILD=1
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) BIN="$(cd "$2" && pwd)"; shift 2 ;;
        --dir) DIR="$2"; shift 2 ;;
        --no-build) BUILD=0; shift ;;
        -h | --help) sed -n '2,12p' "$0"; exit 0 ;;
        *) echo "attack.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
if [ "$BUILD" = 1 ] && [ "$BIN" = "$ROOT/target/release" ]; then
    (cd "$ROOT" && cargo build --release --bins >&2) || exit 2
fi
OWN_DIR=0
[ -n "$DIR" ] || { DIR="$(mktemp -d)"; OWN_DIR=1; }
mkdir -p "$DIR"
cd "$DIR" || exit 2
T=20
FAILED=0
export RUST_LOG=warn
PIDS=()
cleanup() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done
    wait 2>/dev/null
    [ "$OWN_DIR" = 1 ] && rm -rf "$DIR"
}
trap cleanup EXIT

printf '| class | attack | exit | s | says | verdict |\n|---|---|---|---|---|---|\n'

# row CLASS ATTACK EXPECTED_EXIT CHECK -- COMMAND...: runs COMMAND bounded by $T seconds; CHECK
# is a shell condition evaluated afterwards (`true` when there is nothing more to check).
row() {
    local class="$1" attack="$2" want="$3" check="$4"
    shift 5
    local t0 t1 code says verdict
    t0=$(date +%s.%N)
    timeout -k 2 "$T" "$@" >"$DIR/out" 2>&1 </dev/null
    code=$?
    t1=$(date +%s.%N)
    says=$(sed 's/\x1b\[[0-9;]*m//g' "$DIR/out" | grep -v '^\s*$' | grep -v '^\s*[0-9]\+ \(image_cache\|pyramid\)' | grep -v '^level \+kind' | head -n 1 | cut -c1-110 | sed 's/|/\\|/g')
    if [ "$code" = 124 ] || [ "$code" = 137 ]; then
        verdict="HUNG"
    elif [ "$code" != "$want" ]; then
        verdict="exit $code, expected $want"
    elif ! eval "$check"; then
        verdict="check failed: $check"
    else
        verdict="ok"
    fi
    [ "$verdict" = ok ] || FAILED=1
    printf '| %s | %s | %s | %.2f | %s | %s |\n' "$class" "$attack" "$code" "$(echo "$t1 - $t0" | bc)" "$says" "$verdict"
}

fresh() { rm -rf "$DIR/s" && mkdir -p "$DIR/s"; }
victim() { printf 'precious\n' >"$DIR/victim" && chmod 600 "$DIR/victim"; }
intact() { [ "$(cat "$DIR/victim")" = precious ]; }
SVC=(--source hash --size 4096 --clip 256 --tile 64)
place() { echo --name "$1" --shm-dir "$DIR/s" --socket "$DIR/s/clipmap-$1.sock"; }
prepared() { rm -rf "$DIR/p" && cp -r "$ROOT/config_examples/prepared" "$DIR/p"; }
ping() { timeout 5 python3 -c '
import socket,sys
s=socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); s.sendall(b"PING\n"); print(s.recv(100).decode().strip())' "$1" 2>/dev/null | grep -q pong; }

# 1. Names in shared directories.
fresh; victim; ln -s "$DIR/victim" "$DIR/s/clipmap-n.lock"
row names "symlink at the lock name" 2 intact -- "$BIN/clipmapd" "${SVC[@]}" $(place n)
fresh; victim; ln -s "$DIR/victim" "$DIR/s/clipmap-n.map"
row names "symlink at the mapping name" 2 intact -- "$BIN/clipmapd" "${SVC[@]}" $(place n)
fresh; mkfifo "$DIR/s/clipmap-n.lock"
row names "FIFO at the lock name" 2 true -- "$BIN/clipmapd" "${SVC[@]}" $(place n)
fresh; victim; cp "$DIR/victim" "$DIR/s/clipmap-n.sock"
row names "regular file at the socket name" 2 '[ "$(cat "$DIR/s/clipmap-n.sock")" = precious ]' -- "$BIN/clipmapd" "${SVC[@]}" $(place n)
fresh; printf squat >"$DIR/s/clipmap-n.lock"
flock "$DIR/s/clipmap-n.lock" sleep 10 & PIDS+=($!)
sleep 0.2
row names "squatter holding the lock" 2 '! grep -q "process 0" "$DIR/out"' -- "$BIN/clipmapd" "${SVC[@]}" $(place n)
fresh
"$BIN/clipmapd" "${SVC[@]}" $(place live) >/dev/null 2>&1 & PIDS+=($!)
for _ in $(seq 100); do ping "$DIR/s/clipmap-live.sock" && break; sleep 0.1; done
row names "second start on a live name" 2 'ping "$DIR/s/clipmap-live.sock"' -- "$BIN/clipmapd" "${SVC[@]}" --name live --shm-dir "$DIR/s" --socket "$DIR/s/other.sock"
row names "second start on a live socket" 2 'ping "$DIR/s/clipmap-live.sock" && [ -e "$DIR/s/clipmap-live.map" ]' -- "$BIN/clipmapd" "${SVC[@]}" --name other --shm-dir "$DIR/s" --socket "$DIR/s/clipmap-live.sock"
sh -c "umask 077; exec '$BIN/clipmapd' ${SVC[*]} $(place wide) --shm-mode 640" >/dev/null 2>&1 & PIDS+=($!)
for _ in $(seq 100); do ping "$DIR/s/clipmap-wide.sock" && break; sleep 0.1; done
row names "--shm-mode 640 under umask 077" 0 true -- sh -c "[ \$(stat -c %a '$DIR/s/clipmap-wide.map') = 640 ] && [ \$(stat -c %a '$DIR/s/clipmap-wide.lock') = 640 ]"

# 2. Files a configuration names.
prepared; rm "$DIR/p/L01/r000.c000.raw"; mkfifo "$DIR/p/L01/r000.c000.raw"; ln -sf /dev/zero "$DIR/p/L01/r000.c001.raw"
row files "tiles that are a FIFO and /dev/zero: check" 1 'grep -q unreadable "$DIR/out"' -- "$BIN/cliptex" check "$DIR/p/hash256.ct"
"$BIN/clipmapd" "$DIR/p/hash256.ct" $(place tiles) >/dev/null 2>&1 & PIDS+=($!)
row files "tiles that are a FIFO and /dev/zero: clipmapd" 0 'ping "$DIR/s/clipmap-tiles.sock"' -- python3 -c '
import json, socket, sys, time
for _ in range(200):
    try:
        s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); s.sendall(b"STATS\n")
        line = s.makefile().readline()
        n = json.loads(line[3:])["engine"]["queue"]["reads_failed"]
        if n >= 2:
            print(f"reads_failed {n}, still serving"); sys.exit(0)
    except (OSError, ValueError, KeyError):
        pass
    time.sleep(0.05)
print("no failed read counted"); sys.exit(1)' "$DIR/s/clipmap-tiles.sock"
mkfifo "$DIR/fifo.ct"
for sub in validate info check; do
    row files "a .ct that is a FIFO: $sub" 2 'grep -q FIFO "$DIR/out"' -- "$BIN/cliptex" "$sub" "$DIR/fifo.ct"
done
row files "a .ct that is a FIFO: clipmapd" 2 'grep -q FIFO "$DIR/out"' -- "$BIN/clipmapd" "$DIR/fifo.ct" --shm-dir "$DIR/s"
prepared; printf 'default_tile /dev/zero\n' >>"$DIR/p/L00.ic"
row files "default_tile /dev/zero: clipmapd" 1 'grep -q "character device" "$DIR/out"' -- "$BIN/clipmapd" "$DIR/p/hash256.ct" --shm-dir "$DIR/s" --name z
row files "default_tile /dev/zero: validate" 1 true -- "$BIN/cliptex" validate "$DIR/p/hash256.ct"

# 3. Input images.
python3 - "$DIR" <<'EOF' || exit 2
import struct, sys, zlib
d = sys.argv[1]
w = h = 64
raw = b"".join(b"\0" + bytes((x * 4) % 256 for x in range(w * 3)) for _ in range(h))
def chunk(t, b):
    return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open(d + "/cut.png", "wb").write(png[: len(png) // 2])
EOF
row images "truncated PNG" 1 'grep -q "cannot decode" "$DIR/out"' -- "$BIN/clipprep" --input "$DIR/cut.png" --tile 32 --clip 32 --format rgb8 --out "$DIR/o1"
# A JPEG to cut: $ATTACK_JPEG, or one made with Pillow when it is installed.
if [ -z "${ATTACK_JPEG:-}" ] && python3 -c 'import PIL' 2>/dev/null; then
    python3 -c 'from PIL import Image; Image.radial_gradient("L").convert("RGB").save("'"$DIR"'/whole.jpg")' && ATTACK_JPEG="$DIR/whole.jpg"
fi
if [ -n "${ATTACK_JPEG:-}" ] && [ -f "$ATTACK_JPEG" ]; then
    head -c $(($(stat -c %s "$ATTACK_JPEG") * 6 / 10)) "$ATTACK_JPEG" >"$DIR/cut.jpg"
    row images "truncated JPEG" 1 'grep -q "cannot decode" "$DIR/out"' -- "$BIN/clipprep" --input "$DIR/cut.jpg" --tile 32 --clip 32 --format rgb8 --out "$DIR/o2"
fi

# 4. Numbers.
row numbers "--max-connections 2^64-1" 1 true -- "$BIN/clipmapd" "${SVC[@]}" $(place m) --max-connections 18446744073709551615
row numbers "--budget-ms 0.0000001" 1 true -- "$BIN/clipmapd" "${SVC[@]}" $(place m) --budget-ms 0.0000001
row numbers "--tile 1" 1 true -- "$BIN/clipmapd" --source hash --size 65536 --clip 1024 --tile 1 $(place m)
row numbers "roam --frames 2^64-1" 1 true -- "$BIN/cliptex" roam --source hash --size 4096 --clip 256 --flight straight:1 --frames 18446744073709551615
cat >"$DIR/huge.ct" <<'EOF'
ct_version2.0
ext_format PFTEX_PACK_8
int_format PFTEX_RGB_8
img_format PFTEX_RGB
virt_size 1048576 1048576 1
clip_size 1024
tile_format t.%d.r%d.c%d.raw
tile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S
tile_size 65536 65536 1
EOF
row numbers "tile_size 65536^2: validate" 1 true -- "$BIN/cliptex" validate "$DIR/huge.ct"
row numbers "tile_size 65536^2: clipmapd" 1 true -- "$BIN/clipmapd" "$DIR/huge.ct" --shm-dir "$DIR/s" --name h

# 5. Writes.
if [ -e /dev/full ]; then
    row writes "dump to /dev/full" 2 true -- "$BIN/cliptex" dump "$ROOT/config_examples/prepared/hash256.ct" --level 0 --out /dev/full
fi

# 6. Exit codes.
for tool in cliptex icache clipprep clipbench clipmapd; do
    row exits "$tool --no-such-option" 1 true -- "$BIN/$tool" --no-such-option
done

exit "$FAILED"
