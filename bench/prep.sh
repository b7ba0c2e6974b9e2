#!/usr/bin/env bash
# Preparation benchmark: peak memory and throughput of `clipprep` on a large RGBA8 texture,
# against the disk's sequential write bandwidth (dd) and a peer tool (vips dzsave), all measured
# in the same run, each several times; prints a table of medians and ratios.
#
# Usage: bench/prep.sh [--size N] [--repeats R] [--dir DIR] [--install-peers] [--no-peer]
#   --size N          level-0 edge in texels (power of two; default 32768)
#   --repeats R       measurements of each command (default 3)
#   --dir DIR         scratch directory on the disk under test (default: bench/scratch)
#   --install-peers   apt-get install the peer tool (libvips-tools) and GNU time if missing
#   --no-peer         skip the image input and the peer tool
#
# Disk use at any time: at most one pyramid (about 4/3 x N^2 x 4 bytes) plus, with the peer,
# the input image (N^2 x 4 bytes). Everything is removed at the end.
set -euo pipefail

SIZE=32768
REPEATS=3
INSTALL=0
PEER=1
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
DIR="$ROOT/bench/scratch"
while [ $# -gt 0 ]; do
    case "$1" in
        --size) SIZE="$2"; shift 2 ;;
        --repeats) REPEATS="$2"; shift 2 ;;
        --dir) DIR="$2"; shift 2 ;;
        --install-peers) INSTALL=1; shift ;;
        --no-peer) PEER=0; shift ;;
        -h | --help) sed -n '2,14p' "$0"; exit 0 ;;
        *) echo "prep.sh: unknown argument $1" >&2; exit 2 ;;
    esac
done
TILE=256
CLIP=1024

if [ "$INSTALL" = 1 ]; then
    need=()
    [ -x /usr/bin/time ] || need+=(time)
    [ "$PEER" = 1 ] && ! command -v vips > /dev/null && need+=(libvips-tools)
    if [ ${#need[@]} -gt 0 ]; then
        apt-get install -y --no-install-recommends "${need[@]}"
    fi
fi
[ -x /usr/bin/time ] || { echo "prep.sh: /usr/bin/time (GNU time) is missing; pass --install-peers" >&2; exit 2; }
if [ "$PEER" = 1 ] && ! command -v vips > /dev/null; then
    echo "prep.sh: vips is missing; pass --install-peers or --no-peer" >&2
    exit 2
fi

cd "$ROOT"
cargo build --release --quiet --bin clipprep
LOAD_START=$(cut -d' ' -f1-3 /proc/loadavg)
CLIPPREP="$ROOT/target/release/clipprep"

mkdir -p "$DIR"
WORK="$(mktemp -d "$DIR/run.XXXXXX")"
cleanup() { rm -rf "$WORK"; }
trap cleanup EXIT

# Bytes of the whole pyramid: every level of an N x N RGBA8 texture down to 1 x 1.
BYTES=0
s=$SIZE
while [ "$s" -ge 1 ]; do
    BYTES=$((BYTES + s * s * 4))
    s=$((s / 2))
done
MIB4=$((4 << 20))
COUNT=$(((BYTES + MIB4 - 1) / MIB4))
DD_BYTES=$((COUNT * MIB4))

now() { date +%s.%N; }
# Runs "$@" under GNU time; appends "seconds rss_kib" (wall time including a final sync) to $LOG.
measure() {
    local log="$1"
    shift
    local t0 t1
    sync
    t0=$(now)
    /usr/bin/time -v -o "$WORK/time.txt" "$@" > "$WORK/stdout.txt" 2> "$WORK/stderr.txt" || {
        cat "$WORK/stderr.txt" >&2
        exit 1
    }
    sync
    t1=$(now)
    local rss
    rss=$(awk -F': ' '/Maximum resident set size/ {print $2}' "$WORK/time.txt")
    echo "$(echo "$t1 - $t0" | bc -l) $rss" >> "$log"
}
median() { sort -g | awk '{v[NR] = $1} END {if (NR % 2) print v[(NR + 1) / 2]; else print (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
col() { awk -v c="$2" '{print $c}' "$1"; }

DD_CMD=(dd if=/dev/zero of="$WORK/dd.bin" bs=4M count="$COUNT" conv=fdatasync)
HASH_CMD=("$CLIPPREP" --source hash --size "$SIZE" --tile "$TILE" --clip "$CLIP" --format rgba8 --out "$WORK/hash" --quiet)
INPUT="$WORK/input.tif"
IMG_CMD=("$CLIPPREP" --input "$INPUT" --tile "$TILE" --clip "$CLIP" --format rgba8 --out "$WORK/img" --quiet)
VIPS_CMD=(vips dzsave "$INPUT" "$WORK/dz" --suffix .tif --tile-size "$TILE" --overlap 0 --depth onepixel)

echo "pyramid: ${SIZE}x${SIZE} RGBA8, $BYTES bytes; dd: $DD_BYTES bytes; repeats: $REPEATS" >&2
for i in $(seq "$REPEATS"); do
    echo "round $i: dd" >&2
    measure "$WORK/dd.log" "${DD_CMD[@]}"
    rm -f "$WORK/dd.bin"
    echo "round $i: clipprep --source hash" >&2
    measure "$WORK/hash.log" "${HASH_CMD[@]}"
    HASH_WRITTEN=$(du -sb "$WORK/hash" | awk '{print $1}')
    rm -rf "$WORK/hash"
done

if [ "$PEER" = 1 ]; then
    # The peer's input: smooth noise, 4 identical 8-bit bands, an uncompressed strip TIFF
    # (clipprep streams it strip by strip; vips reads it sequentially).
    echo "making the ${SIZE}x${SIZE} input image" >&2
    vips perlin "$WORK/noise.v" "$SIZE" "$SIZE" --uchar
    vips bandjoin "$WORK/noise.v $WORK/noise.v $WORK/noise.v $WORK/noise.v" "$INPUT"
    rm -f "$WORK/noise.v"
    for i in $(seq "$REPEATS"); do
        echo "round $i: clipprep --input" >&2
        measure "$WORK/img.log" "${IMG_CMD[@]}"
        IMG_WRITTEN=$(du -sb "$WORK/img" | awk '{print $1}')
        rm -rf "$WORK/img"
        echo "round $i: vips dzsave" >&2
        measure "$WORK/vips.log" "${VIPS_CMD[@]}"
        VIPS_WRITTEN=$(du -sb "$WORK/dz_files" | awk '{print $1}')
        rm -rf "$WORK/dz_files" "$WORK/dz.dzi"
    done
fi

mbps() { echo "$1 / $2 / 1048576" | bc -l | xargs printf '%.0f'; }
row() { # name written_bytes log
    local t r
    t=$(col "$3" 1 | median)
    r=$(col "$3" 2 | median)
    printf '| %s | %s | %.2f | %s | %.0f |\n' "$1" "$2" "$t" "$(mbps "$2" "$t")" "$(echo "$r / 1024" | bc -l)"
}
DD_T=$(col "$WORK/dd.log" 1 | median)
HASH_T=$(col "$WORK/hash.log" 1 | median)
echo
echo "machine: $(nproc) cores, $(awk -F': ' '/model name/ {print $2; exit}' /proc/cpuinfo), $(df -h "$DIR" | awk 'NR == 2 {print $1 " (" $2 ")"}'), $(free -g | awk '/Mem:/ {print $2}') GiB memory"
echo "load average (1, 5, 15 min) at the start: $LOAD_START; at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| command | bytes written | median s | MiB/s | median peak RSS MiB |"
echo "|---|---|---|---|---|"
row "dd (baseline)" "$DD_BYTES" "$WORK/dd.log"
row "clipprep --source hash" "$HASH_WRITTEN" "$WORK/hash.log"
if [ "$PEER" = 1 ]; then
    row "clipprep --input TIFF" "$IMG_WRITTEN" "$WORK/img.log"
    row "vips dzsave (peer)" "$VIPS_WRITTEN" "$WORK/vips.log"
fi
echo
printf 'hash throughput / dd bandwidth: %.2f (goal >= 0.5)\n' \
    "$(echo "($HASH_WRITTEN / $HASH_T) / ($DD_BYTES / $DD_T)" | bc -l)"
printf 'hash peak RSS: %.0f MiB (goal < 512)\n' "$(echo "$(col "$WORK/hash.log" 2 | median) / 1024" | bc -l)"
if [ "$PEER" = 1 ]; then
    IMG_T=$(col "$WORK/img.log" 1 | median)
    VIPS_T=$(col "$WORK/vips.log" 1 | median)
    printf 'clipprep --input time / vips dzsave time: %.2f\n' "$(echo "$IMG_T / $VIPS_T" | bc -l)"
fi
echo
echo "samples (seconds rss_kib):"
for f in dd hash img vips; do
    [ -f "$WORK/$f.log" ] && echo "  $f: $(tr '\n' ';' < "$WORK/$f.log")"
done
echo
echo "commands (SCRATCH is the scratch directory):"
show() { local c="$*"; c="${c//$WORK/SCRATCH}"; echo "  ${c//$ROOT\//}"; }
show "${DD_CMD[@]}"
show "${HASH_CMD[@]}"
if [ "$PEER" = 1 ]; then
    echo "  vips perlin SCRATCH/noise.v $SIZE $SIZE --uchar"
    echo "  vips bandjoin 'SCRATCH/noise.v SCRATCH/noise.v SCRATCH/noise.v SCRATCH/noise.v' SCRATCH/input.tif"
    show "${IMG_CMD[@]}"
    show "${VIPS_CMD[@]}"
fi
echo "  (each timed as: sync; start; /usr/bin/time -v COMMAND; sync; stop)"
