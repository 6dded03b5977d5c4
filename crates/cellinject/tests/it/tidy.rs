//! Size rules of the source (after rust-analyzer's `tidy`): no source file over
//! 1,000 lines and no function over 150, counted without a file's `#[cfg(test)]`
//! module (kept at its end) and without `tests/` folders. The files and functions
//! over them today are listed with their size: a listed one may shrink, not grow,
//! and leaves the list once it is within the rule (the test says so), so the debt
//! only goes down. And a thin binary: `crates/cellinject/src` holds at most a tenth
//! of those lines (it parses, calls one library function per command, and prints).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Longest source file, in lines.
const FILE_LINES: usize = 1000;
/// Longest function, in lines from its `fn` to its closing brace.
const FN_LINES: usize = 150;
/// Largest share of the lines under `crates/*/src` the binary's `src` may hold.
const BINARY_SHARE: f64 = 0.10;

/// Files over [`FILE_LINES`] today, with their length (issue 38 splits them).
const LONG_FILES: &[(&str, usize)] = &[];

/// Functions over [`FN_LINES`] today (file, name, length).
const LONG_FNS: &[(&str, &str, usize)] = &[];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Every `.rs` file under `crates/*/src`, as a path from the workspace root.
fn sources() -> Vec<String> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    for c in std::fs::read_dir(root().join("crates")).unwrap() {
        let src = c.unwrap().path().join("src");
        if src.is_dir() {
            walk(&src, &mut files);
        }
    }
    let root = root().canonicalize().unwrap();
    let mut out: Vec<String> = files
        .iter()
        .map(|p| {
            p.canonicalize()
                .unwrap()
                .strip_prefix(&root)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/")
        })
        .collect();
    out.sort();
    out
}

/// A file's lines before its `#[cfg(test)]` module.
fn code_lines(text: &str) -> Vec<&str> {
    text.lines()
        .take_while(|l| l.trim() != "#[cfg(test)]")
        .collect()
}

/// `line` without its string and character literals and its `//` comment (enough to
/// count braces in this code base's style).
fn braces_only(line: &str) -> String {
    let mut out = String::new();
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' => {
                while let Some(d) = chars.next() {
                    match d {
                        '\\' => {
                            chars.next();
                        }
                        '"' => break,
                        _ => {}
                    }
                }
            }
            '\'' => {
                // A char literal ('{', '\n') is skipped; a lifetime ('a) is not one.
                let rest: String = chars.clone().take(3).collect();
                if rest.starts_with('\\') {
                    chars.nth(2);
                } else if rest.chars().nth(1) == Some('\'') {
                    chars.nth(1);
                }
            }
            '/' if chars.peek() == Some(&'/') => break,
            _ => out.push(c),
        }
    }
    out
}

/// The name of the function a line declares, if it does.
fn declares(line: &str) -> Option<&str> {
    let mut words = line.split_whitespace().peekable();
    while let Some(w) = words.next() {
        match w {
            "pub" | "const" | "async" | "unsafe" | "extern" | "default" => {}
            w if w.starts_with("pub(") => {}
            "fn" => {
                let name = words.next()?;
                let end = name
                    .find(|c: char| !(c.is_alphanumeric() || c == '_'))
                    .unwrap_or(name.len());
                return Some(&name[..end]);
            }
            _ => return None,
        }
    }
    None
}

/// Each function of `lines` with its length, from its `fn` to its closing brace.
fn functions(lines: &[&str]) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let Some(name) = declares(l) else { continue };
        let mut depth = 0i64;
        let mut opened = false;
        for (j, m) in lines.iter().enumerate().skip(i) {
            let b = braces_only(m);
            for c in b.chars() {
                match c {
                    '{' => {
                        depth += 1;
                        opened = true;
                    }
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            if !opened && b.trim_end().ends_with(';') {
                break; // a declaration without a body
            }
            if opened && depth <= 0 {
                out.push((name.to_string(), j - i + 1));
                break;
            }
        }
    }
    out
}

#[test]
fn no_file_over_1000_lines_and_no_function_over_150_beyond_the_listed_debt() {
    let files: BTreeMap<&str, usize> = LONG_FILES.iter().copied().collect();
    let fns: BTreeMap<(&str, &str), usize> =
        LONG_FNS.iter().map(|&(f, n, l)| ((f, n), l)).collect();
    let mut faults = Vec::new();
    let mut seen_fns = Vec::new();
    for path in sources() {
        let text = std::fs::read_to_string(root().join(&path)).unwrap();
        let lines = code_lines(&text);
        let n = lines.len();
        match files.get(path.as_str()) {
            None if n > FILE_LINES => faults.push(format!(
                "{path}: {n} lines (at most {FILE_LINES}): split it by responsibility"
            )),
            Some(&was) if n > was => faults.push(format!(
                "{path}: {n} lines, listed at {was}: a listed file may only shrink"
            )),
            Some(_) if n <= FILE_LINES => faults.push(format!(
                "{path}: {n} lines, within the rule: take it off LONG_FILES"
            )),
            _ => {}
        }
        for (name, len) in functions(&lines) {
            let key = (path.as_str(), name.as_str());
            match fns.get(&key) {
                None if len > FN_LINES => faults.push(format!(
                    "{path}: fn {name} is {len} lines (at most {FN_LINES})"
                )),
                Some(&was) => {
                    seen_fns.push((path.clone(), name.clone()));
                    if len > was {
                        faults.push(format!(
                            "{path}: fn {name} is {len} lines, listed at {was}: it may only shrink"
                        ));
                    } else if len <= FN_LINES {
                        faults.push(format!(
                            "{path}: fn {name} is {len} lines, within the rule: take it off LONG_FNS"
                        ));
                    }
                }
                None => {}
            }
        }
    }
    for &(f, n, _) in LONG_FNS {
        if !seen_fns.iter().any(|(p, m)| p == f && m == n) {
            faults.push(format!(
                "{f}: fn {n} is listed in LONG_FNS but gone: take it off"
            ));
        }
    }
    assert!(faults.is_empty(), "{}", faults.join("\n"));
}

#[test]
fn the_binary_holds_at_most_a_tenth_of_the_source() {
    let (mut binary, mut all) = (0usize, 0usize);
    for f in sources() {
        let n = code_lines(&std::fs::read_to_string(root().join(&f)).unwrap()).len();
        all += n;
        if f.starts_with("crates/cellinject/src/") {
            binary += n;
        }
    }
    let share = binary as f64 / all as f64;
    assert!(
        share <= BINARY_SHARE,
        "crates/cellinject/src holds {binary} of {all} source lines ({:.1} %, at most {:.0} %): move what is not parsing or printing into a library crate",
        share * 100.0,
        BINARY_SHARE * 100.0
    );
}

#[test]
fn the_counter_counts_bodies_and_skips_braces_in_literals() {
    let code = [
        "pub(crate) fn a(x: &str) -> char {",
        "    let s = \"}}{\"; // }",
        "    let c = '{';",
        "    if x.is_empty() { '}' } else { 'a' }",
        "}",
        "fn b<'a>(x: &'a str) -> &'a str {",
        "    x",
        "}",
        "trait T { fn c(&self); }",
    ];
    assert_eq!(
        functions(&code),
        vec![("a".to_string(), 5), ("b".to_string(), 3)]
    );
    assert_eq!(code_lines("a\n#[cfg(test)]\nmod tests {}\n"), vec!["a"]);
}

/// A library that skips its documentation tests (`doctest = false`, which spares CI
/// rustdoc's empty run) has no example in its documentation for them to test: no
/// fenced block in a `///` or `//!` comment that rustdoc would compile (one with no
/// language, `rust`, or rustdoc's attributes; `toml` and `text` blocks are shown,
/// not compiled). An example added there needs the line removed, or it would never
/// be compiled.
#[test]
fn a_crate_that_skips_doc_tests_has_no_examples_in_its_docs() {
    let mut skipping = 0;
    for file in sources() {
        let krate = file.split('/').nth(1).unwrap().to_string();
        let manifest =
            std::fs::read_to_string(root().join("crates").join(&krate).join("Cargo.toml")).unwrap();
        if !manifest.lines().any(|l| l.trim() == "doctest = false") {
            continue;
        }
        skipping += 1;
        let text = std::fs::read_to_string(root().join(&file)).unwrap();
        let mut open = false;
        for (k, line) in text.lines().enumerate() {
            let t = line.trim_start();
            let doc = t.strip_prefix("///").or_else(|| t.strip_prefix("//!"));
            let Some(info) = doc.and_then(|d| d.trim_start().strip_prefix("```")) else {
                continue;
            };
            if !open {
                let lang = info.split(',').next().unwrap_or("").trim();
                let compiled = lang.is_empty()
                    || lang == "rust"
                    || ["no_run", "should_panic", "compile_fail", "edition"]
                        .iter()
                        .any(|a| lang.starts_with(a));
                assert!(
                    !compiled,
                    "{file}:{}: a Rust example in the docs of a crate with `doctest = false`",
                    k + 1
                );
            }
            open = !open;
        }
    }
    assert!(
        skipping > 0,
        "no crate skips its doc tests: the rule checks nothing"
    );
}
