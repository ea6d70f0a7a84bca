#!/usr/bin/env bash
# The main job: set-up (idempotent), the data the episodes need, then a recorded and scored run of the
# five nodes with the shipped default models on 3 near-target test episodes. Extra arguments go to
# scripts/run_pipeline.py (e.g. --episodes 10 --controller random --out runs/mine).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/setup.sh"
set +eu  # env.sh sources colcon's setup.bash, which is not written for errexit/nounset
source "$ROOT/env.sh"
set -eu
cd "$ROOT"
exec python scripts/run_pipeline.py --episodes 3 "$@"
