#!/usr/bin/env bash
# The data of issue 27's Cube Handoff Stage + Random-time variants, collected with their seeded commands and
# joined into one training view (docs/results/random_time.md, docs/results/learning_rate.md):
#
#   bash scripts/cube_mix_data.sh mixsr400sf      # 200 Stage + 200 Random-time (~33 min on the 2-core machine)
#   bash scripts/cube_mix_data.sh mixs400r200sf   # 400 Stage + 200 Random-time (the first four collections too)
#   bash scripts/cube_mix_data.sh mixsr400sfcw25  # mixsr400sf's data, every Random-time frame weighing 0.25 in the
#                                                 # losses (train with --policy.sample_weights=true and the
#                                                 # camera arm's --policy.loss_weight_dims=[14,...,20])
#   bash scripts/cube_mix_data.sh mixsr400sfrw25  # mixsr400sf's data, the Random-time recovery frames weighing 0.25
#                                                 # (train with --policy.sample_weights=true)
#   bash scripts/cube_mix_data.sh mixsr400sfco25  # mixsr400sf's data, the Random-time frames outside the view
#                                                 # recoveries weighing 0.25 (train with --policy.sample_weights=true
#                                                 # and the camera arm's --policy.loss_weight_dims=[14,...,20])
#   bash scripts/cube_mix_data.sh mixs400r200sq200sf  # mixs400r200sf's 600 episodes, then 200 Stage episodes
#                                                 # whose expert grasps square to the table (`--square-grasps`,
#                                                 # seeds 400 and 600), episodes 600-799 of the view
#   bash scripts/cube_mix_data.sh dartsf512_square  # one source alone (any named below): its collection and
#                                                 # points view, no join (the square-grasp protocol pilot's data)
#
# Every source is 100 DART (0.01) demonstrations with 512 self-filtered points: Stage from seeds 0, 300, 700, 850,
# Random-time from seeds 100, 500, square-grasp Stage from 400, 600 (demonstrations stay below seed 1000:
# 1000-1039 validate, 2000 and up test).
# Each step runs once: a collection leaves a marker beside its dataset when it has finished (bavo-collect resumes
# a killed one), a view is built when its folder is absent, and the joined view leaves a marker too (a folder
# without one is an interrupted join and is built again). Run it again after a stop.
set -euo pipefail
cd "$(dirname "$0")/.."
name=${1:?usage: cube_mix_data.sh mixsr400sf|mixs400r200sf|mixsr400sfcw25|mixsr400sfrw25|mixsr400sfco25|mixs400r200sq200sf}
T=cube_handoff D=outputs/datasets/bavo_${T}
sources="dartsf512 dartsf512b dartsf512_random dartsf512_randomb"  # 200 Stage + 200 Random-time
random_weight="" weigh=()  # a ROOT:EPISODES:WEIGHT suffix for the Random-time sources, its mix_views.py --weigh
collection() {  # source name -> "condition first-seed"
    case "$1" in
        dartsf512) echo "stage 0" ;; dartsf512b) echo "stage 300" ;; dartsf512c) echo "stage 700" ;;
        dartsf512d) echo "stage 850" ;; dartsf512_random) echo "random 100" ;; dartsf512_randomb) echo "random 500" ;;
        dartsf512_square) echo "stage 400 --square-grasps" ;; dartsf512_squareb) echo "stage 600 --square-grasps" ;;
    esac
}
if [ -n "$(collection "$name")" ]; then sources=$name; else  # one source: no join
case "$name" in
    mixsr400sf) ;;
    mixs400r200sf) sources="dartsf512 dartsf512b dartsf512c dartsf512d dartsf512_random dartsf512_randomb" ;;
    mixs400r200sq200sf) sources="dartsf512 dartsf512b dartsf512c dartsf512d dartsf512_random dartsf512_randomb
                                 dartsf512_square dartsf512_squareb" ;;
    mixsr400sfcw25) random_weight=:0.25 weigh=(--weigh all) ;;
    mixsr400sfrw25) random_weight=:0.25 weigh=(--weigh recovery) ;;
    mixsr400sfco25) random_weight=:0.25 weigh=(--weigh outside-recovery) ;;
    *) echo "cube_mix_data: no variant named '$name' (mixsr400sf, mixs400r200sf, mixsr400sfcw25," \
            "mixsr400sfrw25, mixsr400sfco25 or mixs400r200sq200sf, or one source such as dartsf512_square)" >&2
        exit 2 ;;
esac
fi
args=()
for s in $sources; do
    read -r condition seed flags <<<"$(collection "$s")"
    if [ ! -f "${D}_$s.collected" ]; then
        # shellcheck disable=SC2086  # $flags: none, or --square-grasps
        bavo-collect --task $T --condition "$condition" --episodes 100 --execution-noise 0.01 --seed "$seed" \
            --repo-id "local/bavo_${T}_$s" --root "${D}_$s" --workers 2 --n-points 512 --self-filter $flags
        touch "${D}_$s.collected"
    fi
    [ -d "${D}_${s}_points" ] || python -m lerobot_bavo.datasets.views --root "${D}_$s" --view points
    w=""; [ "$condition" = random ] && w=$random_weight
    args+=(--source "${D}_${s}_points:100$w")
done
[ "$sources" = "$name" ] && { echo "[cube_mix_data] ${D}_${name}_points ready"; exit 0; }
out=${D}_${name}_points
if [ ! -f "$out.joined" ]; then
    rm -rf "$out"
    python scripts/mix_views.py --output "$out" "${weigh[@]}" "${args[@]}"
    touch "$out.joined"
fi
echo "[cube_mix_data] $out ready"
