#!/usr/bin/env bash
# Runs the whole test suite (pure + graph tests) after the idempotent set-up.
# Extra arguments go to pytest, e.g. scripts/test.sh -m "not graph" or scripts/test.sh test/io.
# The set-up here includes the opt-in RLRAudioPropagation (setup.sh --with-rlr; licence CC-BY-NC 4.0,
# non-commercial use), so that the rlr backend's tests run too; M2H_WITH_RLR=0 leaves it out (they skip).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ "${M2H_WITH_RLR:-1}" = 1 ]; then
  "$ROOT/scripts/setup.sh" --with-rlr
else
  "$ROOT/scripts/setup.sh"
fi
set +eu  # env.sh sources colcon's setup.bash, which is not written for errexit/nounset
source "$ROOT/env.sh"
cd "$ROOT"
python -m pytest "$@"
code=$?
set -e
if [ "$code" -eq 5 ]; then
  echo "scripts/test.sh: pytest collected no tests; that is a failure here" >&2
  exit 1
fi
exit "$code"
