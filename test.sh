#!/usr/bin/env bash
# The whole test suite: installs what it needs, then runs rustfmt, clippy (host and firmware target), rustdoc, the host
# tests (every virtual-bench scenario among them, on both engines), a simulated hour of the bench's soak, both
# firmware images in release and their size report against the flash / RAM budgets, the images themselves run under
# register-level models of the STM32G4 (rehost/), and the cores on an emulated Cortex-M4 (QEMU).
# Usage: ./test.sh           the whole suite (CI runs exactly this through .ci/run)
#        ./test.sh --quick   rustfmt, clippy for the host and the host tests only: the inner loop, without root (the
#                            Python tools in target/python; no network once they are there)
set -euo pipefail
cd "$(dirname "$0")"

case "${1:-}" in
  "") quick=false ;;
  --quick) quick=true ;;
  *) echo "usage: ./test.sh [--quick]" >&2; exit 2 ;;
esac

TARGET=thumbv7em-none-eabihf
# The images built here stay on the bench: they may accept update files signed with the development key, which a
# firmware build refuses unless asked (keys/README.md; checked at the end).
export LBV_ALLOW_DEV_KEY=1

started=$SECONDS
step() { printf '\n=== [%d:%02d] %s\n' $(((SECONDS - started) / 60)) $(((SECONDS - started) % 60)) "$*"; }
# Wait for a step started in the background, show its output, and stop if it failed.
finish() {
  local status=0
  wait "$2" || status=$?
  cat "$3"
  [ "$status" -eq 0 ] || { echo "$1 failed" >&2; exit 1; }
}
# A step that fails ends the run: the ones still going on beside it end with it.
trap 'jobs -p | xargs -r kill 2>/dev/null || true' EXIT
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

step "toolchain"
rustup component add rustfmt clippy >/dev/null 2>&1 || true
rustup target list --installed | grep -qx "$TARGET" || rustup target add "$TARGET"
# flip-link links the firmware images (.cargo/config.toml): a stack overflow faults instead of corrupting RAM.
command -v flip-link >/dev/null || cargo install flip-link --locked
# Clippy lints what the host build compiles. clippy-driver is rustc with clippy's lints (clippy's README: run it
# "with the same arguments you use for rustc"); as the compiler of the workspace's own crates
# (RUSTC_WORKSPACE_WRAPPER) it lints each as the host tests' build compiles it, so a crate is compiled once, linted
# and built, where `cargo clippy` and then a build would compile it twice. Warnings are errors. Its code is not
# quite rustc's (the images it built were some hundred bytes off): fine for the tests, not for the firmware images,
# which plain rustc builds as a user does. Only the commands that say `linted` use it: a build without it would compile the
# workspace's crates again, and the fuzz targets' nightly check must not use a stable driver.
mkdir -p target
printf '#!/bin/sh\nexec "%s" "$@" -D warnings\n' "$(rustup which clippy-driver)" >target/clippy-rustc
chmod +x target/clippy-rustc
linted() { RUSTC_WORKSPACE_WRAPPER="$PWD/target/clippy-rustc" "$@"; }
# The Python tools (requirements.txt, pinned) live in a virtual environment under target/: no root, and no clash
# with a system Python that keeps pip out (PEP 668). It sees the system's packages, so a machine that has the pinned
# versions installs nothing, and once it is set up pip needs no network. Every python3 below is its.
export PATH="$PWD/target/python/bin:$PATH"
python_tools() {
  [ -x target/python/bin/python3 ] || python3 -m venv --system-site-packages target/python
  target/python/bin/python3 -m pip install --quiet --disable-pip-version-check -r requirements.txt
}
# Debian packages (the full run only: they need root) and the Python tools download and install while the first
# Rust steps compile; the host tests, the first step that needs them, wait for them.
system_packages() {
  # Debian: binutils for the size report, sigrok-cli as the independent I2C decoder the capture tests use,
  # qemu-system-arm for the cores on an emulated Cortex-M4 (without its recommended GUI and firmware packages), and
  # Python's venv where Debian keeps it apart.
  local packages=()
  command -v arm-none-eabi-size >/dev/null || packages+=(binutils-arm-none-eabi)
  command -v sigrok-cli >/dev/null || packages+=(sigrok-cli)
  command -v qemu-system-arm >/dev/null || packages+=(qemu-system-arm)
  python3 -c 'import ensurepip' 2>/dev/null || packages+=(python3-venv)
  if [ ${#packages[@]} -gt 0 ]; then
    as_root apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${packages[@]}" >/dev/null
  fi
  python_tools
}
if $quick; then python_tools; else system_packages; fi >target/packages.log 2>&1 &
packages=$!
cargo --version

step "rustfmt, and every link in the Markdown docs"
cargo fmt --all -- --check
python3 docs/check-links.py

# The firmware (its images, then the development key's refusal, which rebuilds the key's crate) goes on beside the
# host steps below, in a target directory of its own: it shares no compiled crate with them, and one cargo at a time
# holds a target directory. An image's fat LTO keeps one core busy while it links, and the host steps fill the other.
# Its clippy comes after, beside rehost: the images are built by plain rustc, as a user builds them (images built by
# clippy-driver differ from rustc's: the master's by 648 B, so rehost would not run what ships). The builds are
# data, g431_hw::images::BUILDS: one line each of name, crate, features ("-" for none), flash and static RAM budgets,
# the size of the flash region it is linked into and the stack budget, in bytes.
export LBV_FIRMWARE_TARGET_DIR=target/firmware
firmware_images() {
  export CARGO_TARGET_DIR=$LBV_FIRMWARE_TARGET_DIR
  step "firmware images (release, $TARGET)"
  # Each image is kept under target/images/ (a crate's feature builds overwrite one another's ELF); then the cores'
  # image for QEMU.
  mkdir -p target/images
  while read -r name package features _; do
    if [ "$features" = - ]; then flags=(); else flags=(--features "$features"); fi
    cargo build --release --target "$TARGET" -p "$package" "${flags[@]}" --locked
    cp "$LBV_FIRMWARE_TARGET_DIR/$TARGET/release/$package" "target/images/$name"
  done <<<"$builds"
  cargo build --release --target "$TARGET" -p qemu-m4 --locked
}
firmware_lints() {
  export CARGO_TARGET_DIR=$LBV_FIRMWARE_TARGET_DIR
  # Every image, one chip per invocation; then the cores on QEMU, and the update image's checks and streaming
  # verification as the firmware builds them (no_std).
  while read -r _ package features _; do
    if [ "$features" = - ]; then flags=(); else flags=(--features "$features"); fi
    cargo clippy --release --target "$TARGET" -p "$package" "${flags[@]}" --locked -- -D warnings
  done <<<"$builds"
  cargo clippy --release --target "$TARGET" -p qemu-m4 --locked -- -D warnings
  cargo clippy --release --target "$TARGET" -p update-image --features verify,defmt --locked -- -D warnings
}
dev_key_refused() {
  export CARGO_TARGET_DIR=$LBV_FIRMWARE_TARGET_DIR
  step "a firmware build refuses the development key unless asked, in every profile"
  # The key's crate as every firmware build compiles it; last, since it rebuilds that crate. Its build script stops
  # before anything is compiled against the key: in the release profile, and in a check in the dev profile.
  for build in "build --release" "check"; do
    if LBV_ALLOW_DEV_KEY= cargo $build --target "$TARGET" -p update-image --features key --locked \
      >target/dev-key.log 2>&1; then
      echo "cargo $build made a firmware with the development key and no LBV_ALLOW_DEV_KEY=1" >&2
      return 1
    fi
    grep -q "signed with the development key" target/dev-key.log || { cat target/dev-key.log; return 1; }
  done
  echo "refused: $(grep -o 'a firmware build would accept[^(]*' target/dev-key.log | head -1)"
}
firmware() {
  firmware_images
  dev_key_refused
}
if ! $quick; then
  # A run from nothing: incremental compilation would only write caches that no later build of this run reads.
  export CARGO_INCREMENTAL=0
  builds=$(cargo run --quiet --locked -p g431-hw --bin images -- builds)
  partitions=$(cargo run --quiet --locked -p g431-hw --bin images -- partitions)
  firmware >target/firmware.log 2>&1 &
  firmware=$!
fi

# Every host test and tool in one build, as `cargo test` builds them (its profile, and the dev-dependencies'
# features unified in: a build of the tools alone would resolve some crates' features otherwise and compile them
# twice), clippy linting every target as it is compiled; then the protocol crates with their firmware's defmt
# feature, which no host build has. The steps beside the host tests then need no cargo, which would wait for theirs
# (one at a time holds a target directory; LBV_TOOLS_BUILT tells rehost/run.sh and qemu-m4/run.sh; the QEMU image
# comes with the firmware's).
step "clippy (host), linting the host tests' build"
linted cargo build --quiet --locked --profile test --workspace --all-targets
cargo clippy -p tmc-proto -p bat-proto -p crash-record -p update-image --all-targets --features defmt --locked -- -D warnings

if $quick; then
  finish "setting up the Python tools" "$packages" target/packages.log
  step "host tests"
  linted cargo test --workspace --locked
  step "quick checks passed (the whole suite: ./test.sh)"
  exit 0
fi
export LBV_TOOLS_BUILT=1

step "docs (rustdoc, warnings denied: every intra-doc link resolves)"
# With the private items: the firmware crates' docs are for those who work on them, and link to what is theirs.
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --workspace --document-private-items --locked --quiet
finish "installing the Debian and Python packages" "$packages" target/packages.log

# The host tests, and beside them whatever else is ready: an hour of random faults and traffic on the bench (the
# soak: every order held, no watchdog bite, no panic) and the fuzz targets' build, both niced to fill what the
# host tests leave idle, then the firmware's images under rehost's models and the cores on QEMU. Each goes to its
# log, shown below.
linted cargo test --workspace --locked >target/host-tests.log 2>&1 &
host_tests=$!
nice target/debug/lbv bench --scenario soak --duration 3600 --quiet >target/soak.log 2>&1 &
soak=$!
fuzz_check() {
  # One target directory for them all: the crates they share are checked once. A check links nothing, so
  # libFuzzer's C++ sources need not be compiled: libfuzzer-sys takes the library's path instead, and no link ever
  # asks for it.
  rustup toolchain list | grep -q '^nightly' || { echo "no nightly toolchain: skipped"; return 0; }
  for fuzz in tmc-proto/fuzz bat-proto/fuzz crash-record/fuzz lbv-master-fw/fuzz lbv/fuzz update-image/fuzz; do
    CUSTOM_LIBFUZZER_PATH="$PWD/target/fuzz/not-built/libfuzzer.a" \
      cargo +nightly check --manifest-path "$fuzz/Cargo.toml" --bins --quiet --target-dir target/fuzz
  done
}
(renice -n 10 "$BASHPID" >/dev/null && fuzz_check) >target/fuzz.log 2>&1 &
fuzz=$!

finish "the firmware" "$firmware" target/firmware.log
rehost/run.sh >target/rehost.log 2>&1 &
rehost=$!
qemu-m4/run.sh >target/qemu-m4.log 2>&1 &
qemu=$!
firmware_lints >target/firmware-lints.log 2>&1 &
firmware_lints=$!

step "image sizes"
# The flash map of each layout, then each image against its budget and the flash it is linked into. Flash holds
# code, constants (the image information record among them) and the initial values of .data; static RAM is
# .data + .bss + .uninit.
echo "$partitions"
failed=0
while read -r name _ _ flash_budget ram_budget linked _; do
  arm-none-eabi-size -A "target/images/$name" |
    awk -v name="$name" -v fb="$flash_budget" -v rb="$ram_budget" -v linked="$linked" '
    $1 ~ /^\.(vector_table|image_info|text|rodata|data)$/ { flash += $2 }
    $1 ~ /^\.(data|bss|uninit)$/ { ram += $2 }
    END {
      ok = flash <= fb && ram <= rb
      printf "%-25s flash %6d B = %5.1f of %3d KiB (linked into %3d KiB)   static RAM %6d B = %5.1f of %2d KiB   %s\n",
        name, flash, flash / 1024, fb / 1024, linked / 1024, ram, ram / 1024, rb / 1024, ok ? "ok" : "OVER BUDGET"
      exit !ok
    }' || failed=1
done <<<"$builds"
# Where the two applications' code goes, by crate and by module of their own crate.
for image in thruster-fw lbv-master-fw; do
  printf '\n%s, code by crate:\n' "$image"
  python3 g431-hw/bloat.py "target/images/$image" "$image" 12
done
[ "$failed" -eq 0 ] || { echo "an image is over its budget" >&2; exit 1; }

step "clippy ($TARGET), each image's crates and features"
finish "the firmware's clippy" "$firmware_lints" target/firmware-lints.log

step "host tests (every bench scenario is one, on both engines)"
finish "the host tests" "$host_tests" target/host-tests.log

step "fuzz targets build (nightly)"
finish "the fuzz targets' build" "$fuzz" target/fuzz.log

step "the images that ship, run under register-level models of the STM32G4 (Unicorn): boot, registers, buses, faults"
finish rehost "$rehost" target/rehost.log

step "the cores on an emulated Cortex-M4 (QEMU mps2-an386): acceptance loops, vehicle, stack and CPU figures"
finish qemu-m4 "$qemu" target/qemu-m4.log

step "an hour of random faults and traffic on the bench (the soak, run beside the steps above)"
finish soak "$soak" target/soak.log

step "all checks passed"
