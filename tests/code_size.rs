//! The size of the services' code: no source file over 800 lines and no
//! function over 120 lines (in-file tests and the bench binaries aside), so
//! that docs/design.md "Where to change what" points at readable pieces.

use std::path::{Path, PathBuf};

const MAX_FILE_LINES: usize = 800;
const MAX_FN_LINES: usize = 120;

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
fn no_file_over_800_lines_nor_function_over_120_lines() {
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
        if lines.len() > MAX_FILE_LINES {
            problems.push(format!(
                "{rel}: {} lines (at most {MAX_FILE_LINES})",
                lines.len()
            ));
        }
        for (name, n) in functions(&lines) {
            if n > MAX_FN_LINES {
                problems.push(format!(
                    "{rel}: fn {name} has {n} lines (at most {MAX_FN_LINES})"
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
fn the_function_reader_measures_a_function_from_its_line_to_its_brace() {
    let text =
        "fn a() {\n    let x = { 1 };\n}\n\npub(crate) fn b(\n    y: u8,\n) -> u8 {\n    y\n}\n";
    let lines = code_lines(text);
    assert_eq!(
        functions(&lines),
        [("a".to_string(), 3), ("b".to_string(), 5)]
    );
}
