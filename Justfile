# dynslam: the commands a person types. `just --list` shows them.

set shell := ["bash", "-euo", "pipefail", "-c"]

shared := justfile_directory() + "/../shared"
tum := shared + "/data/tum/rgbd_dataset_freiburg1_rpy_first300"

# Build every service (release: the pipeline is only meaningful optimised).
build:
    cargo build --release --workspace

# Run the whole pipeline on a TUM RGB-D folder (default: the shared sequence).
run dataset=tum *args="": build
    ./target/release/dynslam run "{{dataset}}" {{args}}

# The reference evaluation tool evo (PyPI, pinned) in the repo's ignored .cache, for the parity test.
evo:
    #!/usr/bin/env bash
    set -euo pipefail
    venv=.cache/evo-venv
    if [ ! -x "$venv/bin/evo_ape" ]; then
        echo "installing evo 1.38.1 into $venv (once)"
        python3 -m venv "$venv"
        "$venv/bin/pip" install --quiet --disable-pip-version-check evo==1.38.1
    fi

# Format check, lints, unit and integration tests (multi-process, fault injection, evo parity).
test: build evo
    cargo fmt --all -- --check
    cargo clippy --release --workspace --all-targets -- -D warnings
    cargo test --release --workspace

# Accuracy of a trajectory against ground truth (ATE/RPE, as evo computes them).
eval gt est *args="": build
    ./target/release/dynslam eval --gt "{{gt}}" --est "{{est}}" {{args}}

# Transport benchmark: iceoryx2 zero-copy vs a Unix-socket copy (writes bench-results/transport.json).
bench: build
    ./target/release/transport-bench --out bench-results/transport.json
