//! A ratchet on the size of the services' code: no source file over 800
//! lines and no function over 120 lines (in-file tests and the bench
//! binaries aside), except the ones listed below at most at their size
//! today. A new offender, or a listed one that grew, fails; one that shrank
//! below the limit must leave the list (docs/design.md "Where to change
//! what" relies on code cut to readable pieces).

use std::path::{Path, PathBuf};

const MAX_FILE_LINES: usize = 800;
const MAX_FN_LINES: usize = 120;

/// Files over the limit today: (path under services/, lines at most).
const LARGE_FILES: [(&str, usize); 1] = [("slam-core/src/system.rs", 950)];

/// Functions over the limit today: (path under services/, name, lines at most).
const LONG_FUNCTIONS: [(&str, &str, usize); 1] = [
    ("slam-core/src/system.rs", "track_with", 126),
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() {
            // Integration tests, benches and bench binaries are not the product's code.
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if !matches!(name.as_str(), "tests" | "benches" | "bin" | "examples") {
                rust_files(&path, out);
            }
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The file's lines up to its in-file test module.
fn code_lines(text: &str) -> Vec<&str> {
    text.lines()
        .take_while(|l| !l.starts_with("#[cfg(test)]"))
        .collect()
}

/// (name, lines) of every function with a body, by brace matching from
/// its `fn` line (strings and comments with braces are rare enough in this
/// code base to be ignored).
fn functions(lines: &[&str]) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim_start();
        let after = ["pub(crate) fn ", "pub(super) fn ", "pub fn ", "fn "]
            .iter()
            .find_map(|p| {
                t.strip_prefix(p)
                    .or_else(|| t.strip_prefix(&format!("const {p}")[..]))
            });
        let Some(after) = after else { continue };
        let name: String = after
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let (mut depth, mut opened) = (0i32, false);
        for (j, l) in lines[i..].iter().enumerate() {
            for c in l.chars() {
                match c {
                    '{' => {
                        depth += 1;
                        opened = true;
                    }
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            if !opened && l.trim_end().ends_with(';') {
                break; // a declaration without a body
            }
            if opened && depth == 0 {
                out.push((name.clone(), j + 1));
                break;
            }
        }
    }
    out
}

#[test]
fn no_file_over_800_lines_nor_function_over_120_lines_beyond_the_listed_ones() {
    let services = Path::new(env!("CARGO_MANIFEST_DIR")).join("services");
    let mut files = Vec::new();
    rust_files(&services, &mut files);
    assert!(files.len() > 50, "found only {} files", files.len());
    let mut problems = Vec::new();
    for file in &files {
        let rel = file
            .strip_prefix(&services)
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let text = std::fs::read_to_string(file).unwrap();
        let lines = code_lines(&text);
        let allowed_lines = LARGE_FILES
            .iter()
            .find(|(p, _)| *p == rel)
            .map_or(MAX_FILE_LINES, |(_, n)| *n);
        if lines.len() > allowed_lines {
            problems.push(format!(
                "{rel}: {} lines (at most {allowed_lines})",
                lines.len()
            ));
        }
        for (name, n) in functions(&lines) {
            let allowed = LONG_FUNCTIONS
                .iter()
                .find(|(p, f, _)| *p == rel && *f == name)
                .map_or(MAX_FN_LINES, |(_, _, n)| *n);
            if n > allowed {
                problems.push(format!(
                    "{rel}: fn {name} has {n} lines (at most {allowed})"
                ));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "cut these into pieces:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_listed_offenders_are_still_over_the_limit() {
    let services = Path::new(env!("CARGO_MANIFEST_DIR")).join("services");
    for (rel, _) in LARGE_FILES {
        let text = std::fs::read_to_string(services.join(rel)).unwrap();
        assert!(
            code_lines(&text).len() > MAX_FILE_LINES,
            "{rel} is under {MAX_FILE_LINES} lines now: take it off LARGE_FILES"
        );
    }
    for (rel, name, _) in LONG_FUNCTIONS {
        let text = std::fs::read_to_string(services.join(rel)).unwrap();
        let n = functions(&code_lines(&text))
            .into_iter()
            .filter(|(f, _)| f == name)
            .map(|(_, n)| n)
            .max()
            .unwrap_or(0);
        assert!(
            n > MAX_FN_LINES,
            "{rel}: fn {name} is {n} lines now: take it off LONG_FUNCTIONS"
        );
    }
}
