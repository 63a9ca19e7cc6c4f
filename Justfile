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

# Format check, lints, unit and integration tests (multi-process, fault injection).
test: build
    cargo fmt --all -- --check
    cargo clippy --release --workspace --all-targets -- -D warnings
    cargo test --release --workspace

# Transport benchmark: iceoryx2 zero-copy vs a Unix-socket copy (writes bench-results/transport.json).
bench: build
    ./target/release/transport-bench --out bench-results/transport.json
