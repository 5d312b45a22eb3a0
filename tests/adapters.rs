//! Pure code never names OpenCV, GDAL, PROJ or ONNX Runtime: only the adapter modules listed in
//! docs/architecture.md do, each behind its cargo feature. A new module that reaches for one of
//! them fails here (scripts/check-pure.sh builds the crate without the features and checks with
//! ldd that nothing links them).

use std::path::{Path, PathBuf};

/// The adapters (paths under `src/`), as docs/architecture.md lists them.
const ADAPTERS: &[&str] = &[
    "video/",
    "imageio.rs",
    "draw.rs",
    "gis.rs",
    "calibration/detect.rs",
    "calibration/inputs.rs",
    "calibration/oracle.rs",
    "camera/formats/mod.rs",
    "detect/background.rs",
    "detect/motion.rs",
    "detect/onnx.rs",
    "detect/opencv_dnn.rs",
    "export/gis.rs",
    "pipeline/chunk_pass.rs",
    "pipeline/scan.rs",
    "pipeline/views/annotate.rs",
    "pipeline/views/site.rs",
    "pose/oracle.rs",
    "sfm/sift.rs",
    "survey/crs.rs",
    "survey/gis.rs",
    "targets/aruco_cv.rs",
    "terrain/raster.rs",
];

/// Orchestration that still builds OpenCV types itself (to move into adapters): the list may
/// only shrink.
const NOT_YET_MOVED: &[&str] = &[];

const NAMES: &[&str] = &[
    "opencv::",
    "gdal::",
    "gdal_sys::",
    "proj_sys",
    "proj::",
    "ort::",
];

/// Whether `text` names `name` as a path's start (`ort::` but not `export::` or `sort::`).
fn names(text: &str, name: &str) -> bool {
    text.match_indices(name).any(|(i, _)| {
        !text[..i]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_')
    })
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `src/` and every Rust file under it, in order.
fn src_files() -> (PathBuf, Vec<PathBuf>) {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    (src, files)
}

/// `f`'s path under `src`, with forward slashes.
fn relative(src: &Path, f: &Path) -> String {
    f.strip_prefix(src)
        .unwrap()
        .to_string_lossy()
        .replace('\\', "/")
}

#[test]
fn only_adapters_name_opencv_gdal_or_proj() {
    let (src, files) = src_files();
    let mut offenders = Vec::new();
    let mut still_needed = vec![false; NOT_YET_MOVED.len()];
    for f in &files {
        let rel = relative(&src, f);
        let text = std::fs::read_to_string(f).unwrap();
        let named: Vec<&str> = NAMES.iter().copied().filter(|n| names(&text, n)).collect();
        if named.is_empty() || ADAPTERS.iter().any(|a| rel.starts_with(a)) {
            continue;
        }
        match NOT_YET_MOVED.iter().position(|m| *m == rel) {
            Some(k) => still_needed[k] = true,
            None => offenders.push(format!("src/{rel} names {}", named.join(", "))),
        }
    }
    assert!(
        offenders.is_empty(),
        "pure modules naming an adapter's library (move the code into an adapter, or list a new \
         adapter here and in docs/architecture.md):\n{}",
        offenders.join("\n")
    );
    for (m, needed) in NOT_YET_MOVED.iter().zip(still_needed) {
        assert!(
            needed,
            "src/{m} no longer names them: take it off NOT_YET_MOVED"
        );
    }
}

/// The library exports no command-line machinery: clap and anyhow belong to the binary
/// (`src/main.rs` and `src/cli/`).
#[test]
fn the_library_names_neither_clap_nor_anyhow() {
    let (src, files) = src_files();
    let offenders: Vec<String> = files
        .iter()
        .filter_map(|f| {
            let rel = relative(&src, f);
            if rel == "main.rs" || rel.starts_with("cli/") {
                return None;
            }
            let text = std::fs::read_to_string(f).ok()?;
            ["anyhow", "clap::"]
                .iter()
                .any(|n| text.contains(n))
                .then(|| format!("src/{rel}"))
        })
        .collect();
    assert!(
        offenders.is_empty(),
        "library modules naming clap or anyhow (return a typed error; argument parsing goes in \
         src/cli/):\n{}",
        offenders.join("\n")
    );
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    assert!(
        !lib.contains("mod cli"),
        "src/lib.rs must not declare the cli module"
    );
}

/// Every `unsafe` block says why it is sound: a `// SAFETY:` line just above it.
#[test]
fn every_unsafe_block_says_why_it_is_sound() {
    let (_, files) = src_files();
    let mut missing = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            let code = l.trim_start();
            if code.starts_with("//") || !(code.contains("unsafe {") || code.ends_with("unsafe")) {
                continue;
            }
            if !lines[i.saturating_sub(3)..i]
                .iter()
                .any(|p| p.contains("// SAFETY:"))
            {
                missing.push(format!("{}:{}", f.display(), i + 1));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "unsafe blocks without a // SAFETY: line above them:\n{}",
        missing.join("\n")
    );
}

/// A line's code with string and character literals emptied and a `//` comment cut off, so
/// that braces inside them are not counted. `in_string` carries a string literal over lines.
fn code_of(line: &str, in_string: &mut bool) -> String {
    let mut out = String::new();
    let chars: Vec<char> = line.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if *in_string {
            match c {
                '\\' => i += 1,
                '"' => *in_string = false,
                _ => {}
            }
        } else if c == '"' {
            *in_string = true;
        } else if c == '/' && chars.get(i + 1) == Some(&'/') {
            break;
        } else if c == '\'' {
            // A character literal ('x', '\n', '\u{22}'); a lifetime has no closing quote near.
            let close = if chars.get(i + 1) == Some(&'\\') {
                let from = (i + 3).min(chars.len());
                chars[from..]
                    .iter()
                    .position(|&d| d == '\'')
                    .map(|p| from + p)
            } else {
                (chars.get(i + 2) == Some(&'\'')).then_some(i + 2)
            };
            match close {
                Some(k) => i = k,
                None => out.push(c),
            }
        } else {
            out.push(c);
        }
        i += 1;
    }
    out
}

/// No function in `src/` is longer than 150 lines (test modules aside): a longer one is a chain
/// of steps that wants names.
#[test]
fn no_function_in_src_is_over_150_lines() {
    let (_, files) = src_files();
    let mut long = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let mut in_string = false;
        let code: Vec<String> = text.lines().map(|l| code_of(l, &mut in_string)).collect();
        // Where the test module starts, nothing more is counted.
        let end = (0..code.len())
            .find(|&k| {
                code[k].trim() == "#[cfg(test)]"
                    && code
                        .get(k + 1)
                        .is_some_and(|n| n.trim_start().starts_with("mod "))
            })
            .unwrap_or(code.len());
        let mut i = 0;
        while i < end {
            let l = code[i].trim_start();
            let is_fn = [
                "fn ",
                "pub fn ",
                "pub(crate) fn ",
                "pub(super) fn ",
                "const fn ",
            ]
            .iter()
            .any(|p| l.starts_with(p))
                || l.starts_with("pub(in ") && l.contains(") fn ");
            if !is_fn {
                i += 1;
                continue;
            }
            let (mut depth, mut opened, mut j) = (0i64, false, i);
            while j < end {
                for c in code[j].chars() {
                    match c {
                        '{' => {
                            depth += 1;
                            opened = true;
                        }
                        '}' => depth -= 1,
                        // A declaration without a body (a trait's).
                        ';' if !opened && depth == 0 => break,
                        _ => {}
                    }
                }
                if (opened && depth <= 0) || (!opened && code[j].trim_end().ends_with(';')) {
                    break;
                }
                j += 1;
            }
            let lines = j + 1 - i;
            if lines > 150 {
                long.push(format!("{}:{} ({lines} lines)", f.display(), i + 1));
            }
            i = if opened { j + 1 } else { i + 1 };
        }
    }
    assert!(
        long.is_empty(),
        "functions over 150 lines (split them into named steps):\n{}",
        long.join("\n")
    );
}

/// No public library function returns `Result<_, String>`: a caller gets a typed error it can
/// match (docs/conventions.md). `pub(crate)` and `pub(super)` helpers may.
#[test]
fn no_public_function_returns_a_string_error() {
    let (src, files) = src_files();
    let mut offenders = Vec::new();
    for f in &files {
        let rel = relative(&src, f);
        if rel == "main.rs" || rel.starts_with("cli/") {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        for (i, _) in text.match_indices("pub fn ") {
            // The signature: to its body or its end.
            let rest = &text[i..];
            let end = rest.find(['{', ';']).unwrap_or(rest.len());
            let signature: String = rest[..end].split_whitespace().collect::<Vec<_>>().join(" ");
            if let Some((_, returns)) = signature.split_once("->")
                && returns.contains("Result<")
                && returns.trim_end().ends_with(", String>")
            {
                let line = text[..i].lines().count() + 1;
                offenders.push(format!("src/{rel}:{line}: {signature}"));
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "public functions returning Result<_, String> (give them a thiserror type):\n{}",
        offenders.join("\n")
    );
}
