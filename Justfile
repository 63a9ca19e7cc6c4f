# dynslam: the commands a person types. `just --list` shows them.

set shell := ["bash", "-euo", "pipefail", "-c"]

shared := justfile_directory() + "/../shared"
tum := shared + "/data/tum/rgbd_dataset_freiburg1_rpy_first300"
people := ".cache/synth/fr1_rpy_people"
people_front := ".cache/synth/fr1_rpy_people_front"
people_mixed := ".cache/synth/fr1_rpy_mixed_scene"
people_mixed_front := ".cache/synth/fr1_rpy_mixed_none"

# Build every service (release: the pipeline is only meaningful optimised).
build:
    cargo build --release --workspace

# ONNX Runtime 1.31.1 from its PyPI wheel (pinned and verified) into .cache/onnxruntime, and the segmenter at 480/640 input into .cache/models; idempotent.
setup:
    #!/usr/bin/env bash
    set -euo pipefail
    lib=.cache/onnxruntime/libonnxruntime.so.1.31.1
    want=fc44112fbe06d7d689c57e11d3862031f64711007e4ee020f8eed5185fd2c1d3
    if [ ! -f "$lib" ] || ! echo "$want  $lib" | sha256sum --check --status; then
        echo "provisioning ONNX Runtime 1.31.1 from PyPI (onnxruntime wheel) into .cache/onnxruntime"
        rm -rf .cache/wheels && mkdir -p .cache/wheels .cache/onnxruntime
        python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
            --python-version 3.11 --platform manylinux_2_28_x86_64 onnxruntime==1.31.1 -d .cache/wheels
        python3 -c 'import sys, zipfile, glob; z = zipfile.ZipFile(glob.glob(".cache/wheels/onnxruntime-1.31.1-*.whl")[0]); open(sys.argv[1], "wb").write(z.read("onnxruntime/capi/libonnxruntime.so.1.31.1"))' "$lib"
        rm -rf .cache/wheels
    fi
    echo "$want  $lib" | sha256sum --check --quiet || { echo "error: $lib does not match its pinned sha256; delete it and run just setup again" >&2; exit 1; }
    # The segmenter at the input sizes ../shared/models lacks (YOLOv8n-seg 480
    # and 640, YOLO11n-seg 480): the shared 320 export rewritten by
    # tools/yolo_input_size.py (Python onnx, pinned); deterministic, so pinned too.
    models=.cache/models
    if ! (cd "$models" 2>/dev/null && sha256sum --check --status ../../tools/yolo_input_size.sha256); then
        venv=.cache/onnx-venv
        if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import onnx' 2>/dev/null; then
            echo "installing onnx 1.19.1 (Python) into $venv (once)"
            python3 -m venv "$venv"
            "$venv/bin/pip" install --quiet --disable-pip-version-check --no-compile onnx==1.19.1 numpy==2.4.6 protobuf==7.36.2
        fi
        mkdir -p "$models"
        for size in 480 640; do
            "$venv/bin/python" tools/yolo_input_size.py "{{shared}}/models/yolov8n-seg_f32.onnx" "$models/yolov8n-seg_f32_$size.onnx" --size "$size"
        done
        "$venv/bin/python" tools/yolo_input_size.py "{{shared}}/models/yolo11n-seg_320_f32.onnx" "$models/yolo11n-seg_480_f32.onnx" --size 480
        (cd "$models" && sha256sum --check --quiet ../../tools/yolo_input_size.sha256) || { echo "error: the rewritten segmenter models in $models do not match tools/yolo_input_size.sha256 (a different 320 export in ../shared/models or onnx version?)" >&2; exit 1; }
    fi
    (cd assets/vocabulary && sha256sum --check --quiet orb-k10-l4.vocab.sha256) || { echo "error: assets/vocabulary/orb-k10-l4.vocab does not match its pinned sha256; rebuild it with just vocab" >&2; exit 1; }

# Retrain the shipped bag-of-words vocabulary (place recognition) from the shared TUM frames, and pin its sha256.
vocab: build
    ./target/release/dynslam vocab train --out assets/vocabulary/orb-k10-l4.vocab "{{tum}}/rgb"
    cd assets/vocabulary && sha256sum orb-k10-l4.vocab > orb-k10-l4.vocab.sha256

# Whole pipeline -> run folder with report.md. No path: the embedded default scene (rendered room, people walking); else a TUM folder.
run dataset="" *args="": build setup
    #!/usr/bin/env bash
    set -euo pipefail
    if [ -z '{{dataset}}' ]; then
        exec ./target/release/dynslam run {{args}}
    fi
    exec ./target/release/dynslam run '{{dataset}}' {{args}}

# The reference evaluation tool evo (PyPI, pinned) in the repo's ignored .cache, for the parity test.
evo:
    #!/usr/bin/env bash
    set -euo pipefail
    venv=.cache/evo-venv
    if [ ! -x "$venv/bin/evo_ape" ]; then
        echo "installing evo 1.38.1 into $venv (once)"
        python3 -m venv "$venv"
        # --no-compile: Python compiles the modules it imports on first use;
        # compiling every module at install took 12 of evo's 20 s.
        "$venv/bin/pip" install --quiet --disable-pip-version-check --no-compile evo==1.38.1
    fi
    # evo makes its settings folder (~/.evo) on first use; two tests starting
    # it at once on a fresh machine race for the mkdir (FileExistsError).
    "$venv/bin/evo_config" show > /dev/null

# iceoryx2's Python binding (PyPI, the version of our crate) and Pillow in the repo's ignored .cache, for the pose-stream and frame-publisher examples and their tests.
pyiceoryx2:
    #!/usr/bin/env bash
    set -euo pipefail
    venv=.cache/iox2-venv
    if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import iceoryx2, PIL' 2>/dev/null; then
        echo "installing iceoryx2 0.10.0 and Pillow 13.0.0 (Python) into $venv (once)"
        python3 -m venv "$venv"
        "$venv/bin/pip" install --quiet --disable-pip-version-check --no-compile iceoryx2==0.10.0 pillow==13.0.0
    fi

# ROS 2 clients we did not write (PyPI, pinned) in the repo's ignored .cache, for the ROS 2 bridge's tests: eclipse-zenoh (a Zenoh router and subscriber), rosbags (CDR and RIHS01 from its Jazzy type store), zenoh-ros2-sdk (a ROS 2 node on rmw_zenoh's conventions), Pillow (the camera player reads the PNGs).
ros2py:
    #!/usr/bin/env bash
    set -euo pipefail
    venv=.cache/ros2-venv
    if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import zenoh, rosbags, zenoh_ros2_sdk, PIL' 2>/dev/null; then
        echo "installing eclipse-zenoh 1.10.2, rosbags 0.11.9, zenoh-ros2-sdk 0.1.8 and Pillow 13.0.0 (Python) into $venv (once)"
        python3 -m venv "$venv"
        "$venv/bin/pip" install --quiet --disable-pip-version-check --no-compile eclipse-zenoh==1.10.2 rosbags==0.11.9 zenoh-ros2-sdk==0.1.8 pillow==13.0.0
    fi

# Test images that registry packages ship (not committed: their licences are not ours), into .cache/fixtures.
fixtures: evo
    #!/usr/bin/env bash
    set -euo pipefail
    out=.cache/fixtures/bus.png
    if [ ! -f "$out" ]; then
        echo "extracting bus.jpg (people and a bus on a street) from the PyPI wheel ultralytics==8.4.190 (AGPL-3.0)"
        rm -rf .cache/wheels && mkdir -p .cache/wheels .cache/fixtures
        python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: ultralytics==8.4.190 -d .cache/wheels
        .cache/evo-venv/bin/python -c 'import io, sys, glob, zipfile; from PIL import Image; z = zipfile.ZipFile(glob.glob(".cache/wheels/ultralytics-*.whl")[0]); Image.open(io.BytesIO(z.read("ultralytics/assets/bus.jpg"))).convert("RGB").save(sys.argv[1])' "$out"
        rm -rf .cache/wheels
    fi

# Format check, lints, unit and integration tests (multi-process, fault injection, evo parity).
test: build setup evo fixtures pyiceoryx2 ros2py
    cargo fmt --all -- --check
    cargo clippy --release --workspace --all-targets -- -D warnings
    cargo test --release --workspace
    # The portable pixel kernels forced, as on a CPU without the SIMD ones.
    DYNSLAM_SIMD=off cargo test --release --workspace --test orb_kernels
    DYNSLAM_SIMD=off cargo test --release --workspace --test core_tum tracks_the_whole_sequence
    # The SLAM library's example, alone on 30 shared frames.
    # The binary `cargo test` built: `cargo run -p slam-core` would build slam-core
    # again with that package's features alone (~40 s of CI).
    cargo build --release --workspace --examples --quiet
    ./target/release/examples/track_tum "{{tum}}" --limit 30 > /dev/null
    # A newcomer's path through the README: just run, their own TUM folder, real time, kills, the report.
    bash tools/newcomer-path.sh "{{tum}}"

# Accuracy of a trajectory against ground truth (ATE/RPE, as evo computes them).
eval gt est *args="": build
    ./target/release/dynslam eval --gt "{{gt}}" --est "{{est}}" {{args}}

# Model speed: segmenter (input 320, 480, 640) and propagator ms per 640x480 frame, 2 threads (writes bench-results/); sam2 on the tiny test graphs beside lk (our code's cost, not SAM 2's).
bench-models: build setup
    ./target/release/segmenter-bench --threads 2
    ./target/release/propagator-bench --sam2-encoder tests/fixtures/tiny_sam2_encoder.onnx --sam2-decoder tests/fixtures/tiny_sam2_decoder.onnx

# SLAM core speed and accuracy on a TUM folder (default: the shared sequence): ms per frame per step, peak memory, ATE.
bench-slam dataset=tum *args="": build
    ./target/release/slam-bench "{{dataset}}" {{args}}

# SLAM core speed against an older checkout's target/release, alternated in one invocation: extraction alone, extract, track and total p50 ms and ATE, with one and two extraction threads; medians, spreads and new/old ratios.
bench-slam-compare old *args="": build
    python3 tools/compare-slam.py '{{old}}' {{args}}

# SLAM accuracy with frames left out as real time leaves them (the lever of the real-time ATE): ATE on every frame, then on every 2nd frame (2 offsets), every 3rd (3), and 30 % / 45 % dropped at random (3 seeds each); median, mean and worst over the 11 copies, and the median's ratio to every frame's.
bench-dropped dataset=tum *args="": build
    #!/usr/bin/env bash
    set -euo pipefail
    mkdir -p bench-results/dropped
    ate() { ./target/release/slam-bench "{{dataset}}" {{args}} "$@" --out "bench-results/dropped/$(echo "$*" | tr -c 'a-z0-9.\n' _).txt" 2>/dev/null | sed -n 's/^ATE rmse \([0-9.]*\) m.*/\1/p'; }
    full=$(ate --keep-every 1)
    echo "every frame: ATE $full m"
    values=()
    for copy in "--keep-every 2 --offset 0" "--keep-every 2 --offset 1" \
                "--keep-every 3 --offset 0" "--keep-every 3 --offset 1" "--keep-every 3 --offset 2" \
                "--drop-share 0.3 --seed 1" "--drop-share 0.3 --seed 2" "--drop-share 0.3 --seed 3" \
                "--drop-share 0.45 --seed 1" "--drop-share 0.45 --seed 2" "--drop-share 0.45 --seed 3"; do
        v=$(ate $copy)
        echo "$copy: ATE ${v:-none (lost)} m"
        values+=("${v:-1}")
    done
    printf '%s\n' "${values[@]}" | sort -n | awk -v full="$full" '{ v[NR] = $1; s += $1 } END {
        m = v[int((NR + 1) / 2)]
        printf "frames left out, %d copies: median %.4f m (%.2fx every frame), mean %.4f m, worst %.4f m\n", NR, m, m / full, s / NR, v[NR] }'

# The whole pipeline in real time on the shared sequence: 30 and 60 fps, each without and with 2 busy processes pinned to the cores, and 30 fps with 2 busy and the segmenter at 480 px; tracked fps, drops, end-to-end p50/p99, masked share, keyframes and ATE next to lockstep's; and a kill row: 30 fps with the SLAM killed 5 times a run, frames without a pose per kill and the time to the next pose (writes bench-results/realtime.json).
bench-realtime *args="": build setup
    ./target/release/realtime-bench --slam-kills 5 {{args}}

# Real time, this build against an older checkout's target/release, alternated in one invocation: per condition the median and spread of each build and their ratio.
bench-realtime-compare old *args="": build setup
    python3 tools/compare-realtime.py '{{old}}' {{args}}

# The same with people in front of the camera (synth-people: walking across, and in mixed behaviours), 3 runs a condition unless --runs says otherwise (writes bench-results/realtime_people_*.json).
bench-realtime-people *args="": build setup synth-people
    ./target/release/realtime-bench "{{people_front}}" --out bench-results/realtime_people_across.json {{args}}
    ./target/release/realtime-bench "{{people_mixed_front}}" --out bench-results/realtime_people_mixed.json {{args}}

# Remote segmenter over Zenoh: keyframe round trip (loopback and a 20 ms-each-way relay; JPEG and PNG; p50/p99 ms, KB per keyframe; writes bench-results/remote.json), then real time at 30 fps local vs remote (loopback, relay) alternated, and the robot pinned to one core with the 480 px segmenter local vs remote on the other core (bench-results/remote_realtime.json).
bench-remote *args="": build setup
    ./target/release/remote-bench
    python3 tools/bench-remote.py {{args}}

# Real time with the ROS 2 bridge off and on, alternated in one invocation (30 fps, unloaded and with 2 busy processes; a subscriber on a local Zenoh router counts what arrives; writes bench-results/realtime_bridge.json).
bench-realtime-bridge *args="": build setup ros2py
    #!/usr/bin/env bash
    set -euo pipefail
    mkdir -p bench-results
    port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    # The router runs until its stdin (a FIFO held open here) closes, then writes what it counted.
    fifo=$(mktemp -u) && mkfifo "$fifo"
    .cache/ros2-venv/bin/python tests/ros2/client.py listen --count-only --endpoint "tcp/127.0.0.1:$port" --out bench-results/realtime_bridge_received.json < "$fifo" > /dev/null &
    exec 3> "$fifo" && rm "$fifo"
    trap 'exec 3>&-; wait' EXIT
    sleep 2
    ./target/release/realtime-bench --only 30:0,30:2 --bridge "tcp/127.0.0.1:$port" --out bench-results/realtime_bridge.json {{args}}

# Real-time soak of MINUTES on the shared sequence played over and over (a separate `dynslam run`): RSS per process and the map's size per minute; fails when a non-SLAM process grows > 10 MB after minute 1 (writes bench-results/soak.json).
soak minutes="10" *args="": build setup
    ./target/release/soak --minutes {{minutes}} {{args}}

# Our ORB extractor against kornia-imgproc's on the same frames and tracker (own build folder: target/kornia).
bench-orb dataset=tum *args="":
    cargo build --release -p slam --features kornia --bin slam-bench --target-dir target/kornia
    ./target/kornia/release/slam-bench "{{dataset}}" --extractor kornia --out bench-results/slam_trajectory_kornia.txt {{args}}

# Mask quality (segmenter, propagator IoU, by cause, people coming into view) on synth-people: people passing in front of the scene, then hidden by it; walking across, then in mixed behaviours (toward/away, stop and go).
eval-masks: build setup synth-people
    @echo "== people passing in front of the scene ({{people_front}})"
    ./target/release/dynslam masks-eval {{people_front}}
    @echo "== people walking through the scene's geometry, hidden by it ({{people}})"
    ./target/release/dynslam masks-eval {{people}}
    @echo "== mixed behaviours, in front of the scene ({{people_mixed_front}})"
    ./target/release/dynslam masks-eval {{people_mixed_front}}
    @echo "== mixed behaviours, hidden by the scene ({{people_mixed}})"
    ./target/release/dynslam masks-eval {{people_mixed}}

# Mask quality beyond seed 5: synth-people's four sequences and people in front with seeds 1-3 (across and mixed, cached in .cache/synth/seedN_*), one line each (segmenter IoU, propagator IoU, entries masked within 3 frames, early segments) and the means: single sequences move either way with any change, the means over ten are the measure (docs/measurements.md, stop 46).
eval-masks-wide: build setup synth-people
    #!/usr/bin/env bash
    set -euo pipefail
    seqs=("{{people_front}}" "{{people_mixed_front}}" "{{people}}" "{{people_mixed}}")
    for seed in 1 2 3; do
        for behaviour in across mixed; do
            dir=".cache/synth/seed${seed}_${behaviour}"
            {{just_executable()}} --justfile "{{justfile()}}" _synth-once "$dir" "$seed" none "$behaviour"
            seqs+=("$dir")
        done
    done
    for seq in "${seqs[@]}"; do
        ./target/release/dynslam masks-eval "$seq" 2>/dev/null | awk -v name="$(basename "$seq")" '
            /^segmenter +\(keyframes\)/ { seg = $5 }
            /^propagator \(1\.\.10 after\)/ { prop = $6 }
            /^early segments/ { early = $NF }
            /^people coming into view:/ { gsub(",", "", $5); count = $5; in_time = $13 }
            END { printf "%-22s segmenter %s  propagator %s  entries in time %s of %s  early segments %s\n", name, seg, prop, in_time, count, early }'
    done | tee /dev/stderr | awk '{ seg += $3; prop += $5; in_time += $9; count += $11; early += $14; n++ }
        END { printf "mean over %d: segmenter %.3f  propagator %.3f  entries in time %d of %d  early segments %d\n", n, seg / n, prop / n, in_time, count, early }'

# Loop closing on the rendered circuit (dynslam render --path circuit, cached in .cache/scenes): per-frame time and ATE without and with loop closing, 1000 and 250 ORB features (fewer drift more), back to back.
bench-loops: build
    #!/usr/bin/env bash
    set -euo pipefail
    seq=.cache/scenes/circuit-450
    if [ ! -f "$seq/groundtruth.txt" ]; then
        rm -rf "$seq"
        ./target/release/dynslam render "$seq" --path circuit --frames 450
    fi
    for features in 1000 250; do
        for loops in --no-loop-closing ""; do
            echo "== circuit, $features features ${loops:-with loop closing}"
            ./target/release/slam-bench "$seq" --features "$features" $loops \
                --out "bench-results/circuit_${features}${loops:+_no_loops}.txt"
        done
    done
    # Monocular: the loop is a similarity (Sim(3)); the orbit looks in
    # across the room while it goes round (at the default 1000 features).
    orbit=.cache/scenes/orbit-450
    if [ ! -f "$orbit/groundtruth.txt" ]; then
        rm -rf "$orbit"
        ./target/release/dynslam render "$orbit" --path orbit --frames 450
    fi
    for loops in --no-loop-closing ""; do
        echo "== orbit, monocular ${loops:-with loop closing}"
        ./target/release/slam-bench "$orbit" --monocular $loops \
            --out "bench-results/orbit_mono${loops:+_no_loops}.txt"
    done

# People in the shared fr1_rpy sequence (3, seed 5) into .cache/synth: hidden by the nearer scene and passing in front of it, walking across and in mixed behaviours.
synth-people: build (_synth-once people "5" "scene" "across") (_synth-once people_front "5" "none" "across") (_synth-once people_mixed "5" "scene" "mixed") (_synth-once people_mixed_front "5" "none" "mixed")

# Three people over the shared fr1_rpy into DIR, once: objects.json records what a synth wrote; one of another synth_version is from an older synth and is made again.
_synth-once dir seed occlusion behaviour:
    #!/usr/bin/env bash
    set -euo pipefail
    if ! grep -qs '"synth_version": 2,' "{{dir}}/objects.json"; then
        rm -rf "{{dir}}"
        ./target/release/dynslam synth "{{tum}}" "{{dir}}" --objects 3 --seed "{{seed}}" --occlusion "{{occlusion}}" --behaviour "{{behaviour}}"
    fi

# Motion check (services.slam.motion_check) on a box carried through the shared room (dynslam synth --boxes 1, no masks): frames where it is found, features dropped (issue 21's bar: found in 80 %).
eval-motion:
    cargo test --release --test motion_check -- --nocapture

# Ablation table (no masks, ground-truth masks, segmenter every frame, product, blackout) on a dynamic sequence (default: synth-people).
eval-dynamic dataset="" *args="": build setup
    #!/usr/bin/env bash
    set -euo pipefail
    seq='{{dataset}}'
    if [ -z "$seq" ]; then
        "{{just_executable()}}" synth-people
        seq="{{people}}"
    fi
    ./target/release/dynslam ablate "$seq" {{args}}

# Transport benchmarks: iceoryx2 zero-copy vs a Unix-socket copy, and wake-up latency of a WaitSet vs a semaphore event (writes bench-results/transport.json, wakeup.json).
bench: build
    ./target/release/transport-bench --out bench-results/transport.json
    ./target/release/wakeup-bench --out bench-results/wakeup.json
