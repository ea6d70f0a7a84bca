#!/usr/bin/env bash
# Runs the whole test suite (pure + graph tests) after the idempotent set-up.
# Extra arguments go to pytest, e.g. scripts/test.sh -m "not graph" or scripts/test.sh test/io.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
"$ROOT/scripts/setup.sh"
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
