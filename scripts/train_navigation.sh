#!/usr/bin/env bash
# The shipped pi^N + Stop in one command (docs/policies.md, "The shipped pi^N + Stop"): two PPO stages
# kickstarted by the approach teacher, seed 0, one torch thread each (the thread count is part of what
# makes the weights reproducible):
#   stage 1: 1,500 updates (480,000 env steps) from random weights (session 9's pi^N);
#   stage 2: 1,500 more from stage 1's weights (--init-policy: a fresh Adam, lr decaying again from 3e-4).
# A stage that stopped resumes where it stopped; a finished one is not trained again.
#
#     scripts/train_navigation.sh [OUT]        # default runs/policy_navigation
#     cp OUT/stage2/policy.pt m2h_ros/models/default/policy_navigation.pt
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
OUT=${1:-runs/policy_navigation}
"$ROOT/scripts/setup.sh"
set +eu  # env.sh sources colcon's setup.bash, which is not written for errexit/nounset
source "$ROOT/env.sh"
set -eu
cd "$ROOT"
common=(--kind navigation --updates 1500 --episodes 10000 --seed 0 --threads 1 --lr 3e-4 --teacher-coef 1
        --checkpoint-every 50)
python scripts/train_policy.py "${common[@]}" --out "$OUT/stage1"
python scripts/train_policy.py "${common[@]}" --init-policy "$OUT/stage1/policy.pt" --out "$OUT/stage2"
echo "[train_navigation] pi^N + Stop: $OUT/stage2/policy.pt"
