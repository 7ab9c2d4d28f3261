#!/usr/bin/env bash
# The team against each robot alone (thesis Tab. 8.9) on the default mission: per world and
# seed, the mission as it runs by default (robot detections and the submap matcher, no truth),
# the same robots with no radio between them (--solo: single-robot SLAM each), and the
# ground-truth closure source as the upper bound. `python3 sil/scripts/team_vs_solo.py OUT`
# tabulates OUT/WORLD-sSEED-{team,solo,truth}/report.json.
#
#   JOBS=2 sil/scripts/team_vs_solo.sh OUT [SECONDS] [SEED...]
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?output folder}
seconds=${2:-120}
shift $(( $# < 2 ? $# : 2 ))
seeds=("$@")
[ ${#seeds[@]} -gt 0 ] || seeds=(1 2 3 4 5)
cargo build --release -p sil --locked >/dev/null
mkdir -p "$out"
running=0
for world in ${WORLDS:-moon mars}; do
    for seed in "${seeds[@]}"; do
        for variant in team solo truth; do
            case $variant in
                team) extra=() ;;
                solo) extra=(--solo) ;;
                truth) extra=(--truth-loop-closures) ;;
            esac
            dir="$out/$world-s$seed-$variant"
            ./target/release/sil mission --scenario "$world" --seed "$seed" --duration "$seconds" \
                --downscale "${DOWNSCALE:-4}" "${extra[@]}" --out "$dir" >"$dir.log" 2>&1 \
                || echo "run $world $seed $variant failed: see $dir.log" >&2 &
            running=$((running + 1))
            if [ "$running" -ge "${JOBS:-2}" ]; then
                wait -n || true
                running=$((running - 1))
            fi
        done
    done
done
wait
