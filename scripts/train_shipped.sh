#!/usr/bin/env bash
# A shipped policy, or the shipped separator's f^R, in one command, fixed seeds, THREADS torch threads
# (default 2: both cores of the 2-core machines it is sized for; the thread count is part of what makes
# the weights reproducible on one machine kind, other CPUs round differently and drift); a run or stage
# that stopped resumes where it stopped, a finished one is not trained again. docs/design/policies.md has what each learned and how long it took.
#
#   quality:    pi^Q ("The shipped pi^Q"): two stages of PPO on near-target episodes, 32 slots x 20 steps,
#               f^R frozen, the SI-SDR-improvement reward without the final-step term, Adam 3e-4, the
#               target-location auxiliary task (weight 1): stage 1, 1,600 updates (1,024,000 env steps,
#               seed 0, about 70 min); stage 2 from its weights, 1,000 updates (640,000 env steps) on
#               10,000 other episodes (seed 1), a fresh Adam, about 57 min.
#   refiner:    the shipped separator's f^R ("The shipped pi^Q"): the original's third part of pi^Q's
#               training, f^R's L1 trained on the shipped pi^Q's trajectories (the policy trains on too, Adam
#               1e-4; its weights are not shipped), from the pretrained separator: 500 updates (320,000 env
#               steps, seed 2), about 33 min.
#   navigation: pi^N + Stop ("The shipped pi^N + Stop"), kickstarted by the approach teacher throughout, on the
#               48 scenes of split train48, entropy 0.01: stage 1 from the shipped pi^Q's weights (its Stop row
#               new), 1,500 updates (480,000 env steps, seed 1); stages 2-5 each from the stage before (seeds 2-5,
#               a fresh Adam, lr decaying again from 3e-4), 480,000 env steps each: about 1 h 45 min on both cores
#               (AMD EPYC; docs/results/training/policy_navigation).
#   approach:   the far-target composite's walking policy before T^N ("The composite Move2Hear far-target"):
#               the original's three actions, no Stop, rewarded by the geodesic distance gained. It starts from
#               pi^N + Stop's first two stages, the recipe alone (policy_navigation_stage2.pt: 1,500
#               updates each on the 12 train scenes, the kind's entropy 0.2, stage 2 from stage 1's weights), then
#               2,000 updates (640,000 env steps) on the 24 scenes of split train24, entropy 0.02, kickstarted by
#               the approach teacher; the last stage about 40 min with THREADS=1, as it ran; the whole
#               command 1 h 09 min with THREADS=2 (other weights, as good on validation: docs/results/training/policy_approach).
#
#     scripts/train_shipped.sh quality [OUT]      # default runs/policy_quality; THREADS=1 ... for one thread
#     cp OUT/stage2/policy.pt m2h_ros/models/default/policy_quality.pt
#     scripts/train_shipped.sh refiner [OUT]      # default runs/policy_refiner
#     cp OUT/separator.pt m2h_ros/models/default/separator_compact.pt
#     scripts/train_shipped.sh navigation [OUT]   # default runs/policy_navigation
#     cp OUT/stage5/policy.pt m2h_ros/models/default/policy_navigation.pt
#     THREADS=1 scripts/train_shipped.sh approach [OUT]   # default runs/policy_approach
#     cp OUT/navigation_stage2/policy.pt m2h_ros/models/default/policy_navigation_stage2.pt
#     cp OUT/approach/policy.pt m2h_ros/models/default/policy_approach.pt
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
KIND=${1:?usage: scripts/train_shipped.sh quality|refiner|navigation|approach [OUT]}
OUT=${2:-runs/policy_$KIND}
THREADS=${THREADS:-2}
case "$KIND" in quality|refiner|navigation|approach) ;; *) echo "unknown kind '$KIND' (quality, refiner, navigation or approach)" >&2; exit 2 ;; esac
"$ROOT/scripts/setup.sh"
set +eu  # env.sh sources colcon's setup.bash, which is not written for errexit/nounset
source "$ROOT/env.sh"
set -eu
cd "$ROOT"
# The flags a kind's stages share are the recipe file's (params/recipes/policy_KIND.args, also what
# scripts/bench/train.py --shipped-quality times); each stage adds its own. The f^R stage is pi^Q's recipe
# with f^R trained.
recipe=@params/recipes/policy_${KIND/refiner/quality}.args
case "$KIND" in
  quality)
    python scripts/train_policy.py "$recipe" --threads "$THREADS" --updates 1600 --seed 0 --out "$OUT/stage1"
    python scripts/train_policy.py "$recipe" --threads "$THREADS" --updates 1000 --seed 1 \
        --init-policy "$OUT/stage1/policy.pt" --out "$OUT/stage2"
    echo "[train_shipped] pi^Q: $OUT/stage2/policy.pt" ;;
  refiner)
    python scripts/train_policy.py "$recipe" --no-frozen-refiner --lr 1e-4 --threads "$THREADS" --updates 500 \
        --seed 2 --checkpoint-every 25 --init-policy m2h_ros/models/default/policy_quality.pt --out "$OUT"
    echo "[train_shipped] the separator with f^R trained beside pi^Q: $OUT/separator.pt" ;;
  navigation)
    # Stage 1 from pi^Q (it learned to hear and approach near targets: pi^N learns faster from it than from the
    # approach policy or random weights, docs/design/policies.md), then each stage from the one before, other episodes.
    init=m2h_ros/models/default/policy_quality.pt
    for stage in 1 2 3 4 5; do
        python scripts/train_policy.py "$recipe" --threads "$THREADS" --scene-split train48 --entropy-coef 0.01 \
            --seed "$stage" --init-policy "$init" --out "$OUT/stage$stage"
        init=$OUT/stage$stage/policy.pt
    done
    echo "[train_shipped] pi^N + Stop: $OUT/stage5/policy.pt" ;;
  approach)
    # pi^N + Stop's first two stages (the recipe alone: 12 train scenes, entropy
    # 0.2), which is policy_navigation_stage2.pt, then the approach stage from their weights (Stop row dropped).
    navigation=@params/recipes/policy_navigation.args
    python scripts/train_policy.py "$navigation" --threads "$THREADS" --out "$OUT/navigation_stage1"
    python scripts/train_policy.py "$navigation" --threads "$THREADS" --init-policy "$OUT/navigation_stage1/policy.pt" \
        --out "$OUT/navigation_stage2"
    python scripts/train_policy.py "$recipe" --threads "$THREADS" --init-policy "$OUT/navigation_stage2/policy.pt" \
        --out "$OUT/approach"
    echo "[train_shipped] the composite's approach policy: $OUT/approach/policy.pt" ;;
esac
