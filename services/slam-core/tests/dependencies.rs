//! The SLAM core is a library without IPC: its normal dependency tree (what
//! a user of the crate compiles) holds none of the pipeline's crates.

use std::process::Command;

const FORBIDDEN: &[&str] = &[
    "iceoryx2",
    "pipeline",
    "shared-types",
    "clap",
    "camera-reader",
    "ort",
    "supervisor",
];

#[test]
fn the_normal_dependency_tree_holds_no_ipc_crate() {
    let out = Command::new(env!("CARGO"))
        .args([
            "tree",
            "--offline",
            "-p",
            "slam-core",
            "-e",
            "normal",
            "--prefix",
            "none",
            "--format",
            "{p}",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let tree = String::from_utf8_lossy(&out.stdout);
    let names: Vec<&str> = tree
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert!(
        names.contains(&"slam-core") && names.contains(&"nalgebra"),
        "{tree}"
    );
    for crate_name in FORBIDDEN {
        assert!(
            !names.contains(crate_name),
            "slam-core depends on {crate_name}:\n{tree}"
        );
    }
}
