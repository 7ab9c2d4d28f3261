#!/usr/bin/env bash
# The submap matcher's simulation campaign (issue 26): per world and seed a 2-robot lockstep
# mission whose robots' matchers run live, then every truly overlapping pair of the first
# robot's suitable submaps matched in 4D and 6D with the same prior (--evaluate-match-pairs).
# Each run's report.json lands in OUT/WORLD-sSEED/; `python3 sil/scripts/match_campaign.py OUT`
# aggregates them.
#
#   JOBS=2 ROCKS=12 sil/scripts/match_campaign.sh OUT [SECONDS] [DOWNSCALE] [SEED...]
# RADIO: serial (default) or wifi. ROCKS: rocks per 100 m² instead of the presets' (moon 1, mars 3.5): the thesis's matcher needs
# obstacles, and its arena and Etna runs had many more than our open plains.
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?output folder}
seconds=${2:-150}
downscale=${3:-2}
shift $(( $# < 3 ? $# : 3 ))
seeds=("$@")
[ ${#seeds[@]} -gt 0 ] || seeds=(1 2 3 4 5)
cargo build --release -p sil --locked >/dev/null
mkdir -p "$out"
running=0
for world in mars moon; do
    for seed in "${seeds[@]}"; do
        dir="$out/$world-s$seed"
        ./target/release/sil mission --scenario "$world" --seed "$seed" --duration "$seconds" \
            --downscale "$downscale" --evaluate-match-pairs --rocks-in-hub ${ROCKS:+--rocks-per-100m2 "$ROCKS"} \
            ${RADIO:+--radio "$RADIO"} --out "$dir" >"$dir.log" 2>&1 \
            || echo "run $world $seed failed: see $dir.log" >&2 &
        running=$((running + 1))
        if [ "$running" -ge "${JOBS:-2}" ]; then
            wait -n || true
            running=$((running - 1))
        fi
    done
done
wait
