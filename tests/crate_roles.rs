//! Crates by role: a library (the SLAM core, datasets, scheduling, the IPC
//! platform, ...) never depends on a service crate, and a service never on
//! another service. A service crate is one that builds a process: a
//! `src/main.rs`, or a binary under `src/bin/` that is not a bench. What a
//! service's library offers to others belongs in a library crate (as the
//! TUM reader moved from the camera-reader to `datasets`, and the
//! segmenter's and propagator's models to `segmentation` and `propagation`,
//! the V4L2 camera to `live-camera`, the SLAM backends to `slam-backend`).

use std::collections::BTreeSet;
use std::path::Path;

/// Every crate of the workspace but the root (the integration tests, which
/// drive the services): (name, folder).
fn crates(root: &Path) -> Vec<(String, std::path::PathBuf)> {
    let mut dirs = vec![root.join("shared-types")];
    for entry in std::fs::read_dir(root.join("services")).unwrap().flatten() {
        if entry.path().join("Cargo.toml").is_file() {
            dirs.push(entry.path());
        }
    }
    dirs.into_iter()
        .map(|dir| {
            let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
            let name = manifest
                .lines()
                .find_map(|l| l.strip_prefix("name = \""))
                .and_then(|l| l.strip_suffix('"'))
                .unwrap_or_else(|| panic!("{}: no package name", dir.display()))
                .to_string();
            (name, dir)
        })
        .collect()
}

fn is_service(dir: &Path) -> bool {
    let binaries = std::fs::read_dir(dir.join("src/bin"))
        .map(|entries| {
            entries
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
        })
        .unwrap_or_default();
    dir.join("src/main.rs").is_file() || binaries.iter().any(|b| !b.ends_with("-bench.rs"))
}

/// The names in every dependency table of a manifest (normal, dev, build,
/// per target).
fn dependencies(manifest: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut in_table = false;
    for line in manifest.lines().map(str::trim) {
        if line.starts_with('[') {
            in_table = line.ends_with("dependencies]");
            continue;
        }
        if !in_table || line.is_empty() || line.starts_with('#') {
            continue;
        }
        let name: String = line
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '-' || *c == '_')
            .collect();
        if !name.is_empty() {
            out.insert(name);
        }
    }
    out
}

#[test]
fn no_crate_depends_on_a_service_crate() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let all = crates(root);
    let services: BTreeSet<&str> = all
        .iter()
        .filter(|(_, dir)| is_service(dir))
        .map(|(name, _)| name.as_str())
        .collect();
    // The classification itself: a change here must be deliberate.
    for service in [
        "camera-reader",
        "segmenter",
        "propagator",
        "slam",
        "supervisor",
        "bridge",
    ] {
        assert!(
            services.contains(service),
            "{service} should count as a service crate"
        );
    }
    for library in [
        "datasets",
        "run-folder",
        "evaluation",
        "provision",
        "onnx-runtime",
        "pipeline-config",
        "mask-model",
        "slam-core",
        "scheduling",
        "raster",
        "pipeline",
        "shared-types",
    ] {
        assert!(
            !services.contains(library),
            "{library} should count as a library crate"
        );
    }

    let mut found = BTreeSet::new();
    for (name, dir) in &all {
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
        for dep in dependencies(&manifest) {
            if services.contains(dep.as_str()) && dep != *name {
                found.insert((name.clone(), dep));
            }
        }
    }
    assert!(
        found.is_empty(),
        "crates depending on a service crate (move what they use into a library crate): {found:?}"
    );
}

#[test]
fn the_manifest_reader_sees_every_table() {
    let manifest = "[package]\nname = \"x\"\n[dependencies]\na.workspace = true\nb-c = { version = \"1\" }\n# c = 1\n[dev-dependencies]\nd = \"1\"\n[target.'cfg(unix)'.dependencies]\ne = \"1\"\n[features]\nf = []\n";
    let deps: Vec<String> = dependencies(manifest).into_iter().collect();
    assert_eq!(deps, ["a", "b-c", "d", "e"]);
}

/// The libraries that do their work without the IPC platform (`pipeline`:
/// iceoryx2 services, the service runtime) stay free of it, so a tool or
/// another program can use them without the pipeline's transport: the
/// configuration, the model seam, runtime and models, the dataset readers,
/// the timing rules, the SLAM core, the run folder's format.
#[test]
fn libraries_without_ipc_do_not_depend_on_the_pipeline() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let all = crates(root);
    let deps_of = |name: &str| -> BTreeSet<String> {
        let (_, dir) = all.iter().find(|(n, _)| n == name).unwrap();
        dependencies(&std::fs::read_to_string(dir.join("Cargo.toml")).unwrap())
    };
    let ours: BTreeSet<&str> = all.iter().map(|(n, _)| n.as_str()).collect();
    for library in [
        "provision",
        "pipeline-config",
        "mask-model",
        "onnx-runtime",
        "segmentation",
        "propagation",
        "datasets",
        "scheduling",
        "slam-core",
        "scenes",
        "run-folder",
        "evaluation",
        "raster",
    ] {
        // Every crate of ours it reaches, through any dependency table.
        let mut reached = BTreeSet::new();
        let mut todo = vec![library.to_string()];
        while let Some(name) = todo.pop() {
            for dep in deps_of(&name) {
                if ours.contains(dep.as_str()) && reached.insert(dep.clone()) {
                    todo.push(dep);
                }
            }
        }
        assert!(
            !reached.contains("pipeline"),
            "{library} reaches the IPC platform `pipeline` (through {reached:?})"
        );
    }
}

/// Every library of the workspace says what each public item is: its
/// `src/lib.rs` denies missing docs, so an undocumented `pub` fails the
/// build instead of reaching a reader.
#[test]
fn every_library_denies_missing_docs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let undocumented: Vec<String> = crates(root)
        .into_iter()
        .filter_map(|(name, dir)| {
            let lib = std::fs::read_to_string(dir.join("src/lib.rs")).ok()?;
            (!lib.contains("#![deny(missing_docs)]")).then_some(name)
        })
        .collect();
    assert!(
        undocumented.is_empty(),
        "libraries without #![deny(missing_docs)] in src/lib.rs: {undocumented:?}"
    );
}
