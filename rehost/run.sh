#!/usr/bin/env bash
# Runs the firmware images ./test.sh builds (target/images/) under register-level models of the STM32G431 on the
# Unicorn engine, and checks what they do at the register boundary (rehost/README.md). Extra arguments go to
# pytest, e.g. `rehost/run.sh -k thruster -x`.
set -euo pipefail
cd "$(dirname "$0")/.."
# The Python tools of requirements.txt, in the virtual environment ./test.sh sets up.
export PATH="$PWD/target/python/bin:$PATH"
python3 -c 'import unicorn, elftools, pytest' 2>/dev/null || {
  echo "rehost needs the Python tools of requirements.txt: ./test.sh --quick sets them up in target/python" >&2
  exit 1
}
# The test profile and the workspace's features: `cargo test --workspace` has already built everything this needs.
# test.sh has built it (LBV_TOOLS_BUILT): a build here would wait for the host tests' own.
[ -n "${LBV_TOOLS_BUILT:-}" ] || cargo build --quiet --locked --profile test --workspace --bin rehost
exec python3 -m pytest -q -p no:cacheprovider rehost/tests "$@"
