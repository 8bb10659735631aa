//! The library's modules form layers (ARCHITECTURE.md, "Layers"): a module may use modules of
//! its own layer or lower ones, never a higher one. This test reads every `crate::` and
//! `super::` path in `src/` (comments stripped; `src/bin` is an application and may use
//! anything) and fails on an upward use that is not in [`KNOWN_UPWARD`], and on an entry of
//! [`KNOWN_UPWARD`] that no longer occurs (so the list only shrinks). No build, no rendering.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers, lowest first. Keep in step with ARCHITECTURE.md.
const LAYERS: &[&[&str]] = &[
    &["error", "timing"],
    &["limits", "math", "workers"],
    &["geometry", "image_file"],
    &["film"],
    &["light"],
    &["scene"],
    &["analysis"],
    &["guide"],
    &["integrator"],
    &["render"],
    &["compare"],
    &["capi"],
];

/// Upward uses allowed, as (file, module used, why). Empty: keep it so; a new upward use
/// moves the code it needs down instead.
const KNOWN_UPWARD: &[(&str, &str, &str)] = &[];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

/// The source without comments (line, doc and block comments) and without string literals.
fn strip(source: &str) -> String {
    let bytes = source.as_bytes();
    let mut out = String::with_capacity(source.len());
    let mut i = 0;
    while i < bytes.len() {
        let rest = &source[i..];
        if rest.starts_with("//") {
            i += rest.find('\n').unwrap_or(rest.len());
        } else if rest.starts_with("/*") {
            let mut depth = 0;
            while i < bytes.len() {
                if source[i..].starts_with("/*") {
                    depth += 1;
                    i += 2;
                } else if source[i..].starts_with("*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if rest.starts_with('"') {
            i += 1;
            while i < bytes.len() && bytes[i] != b'"' {
                i += if bytes[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
        } else if rest.starts_with("'\"'") {
            i += 3;
        } else {
            let c = rest.chars().next().unwrap();
            out.push(c);
            i += c.len_utf8();
        }
    }
    out
}

/// The module path of a file under `src/` (`src/a/b.rs` and `src/a/b/mod.rs` are `[a, b]`).
fn module_path(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" {
        parts.push(stem.to_string());
    }
    parts
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The top-level modules a file uses: the first segment after `crate::` (or of each item of
/// a `crate::{...}` group), and `super::` paths resolved from the file's module path.
fn used_modules(code: &str, path: &[String]) -> BTreeSet<String> {
    let mut used = BTreeSet::new();
    let word_at = |s: &str| s.chars().take_while(|&c| is_ident(c)).collect::<String>();
    for (at, _) in code.match_indices("crate::") {
        if at > 0 && is_ident(code[..at].chars().next_back().unwrap()) {
            continue;
        }
        let rest = &code[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // Items at the group's top level (a nested group belongs to its item).
            let mut depth = 0;
            let mut item_start = true;
            for (i, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => item_start = true,
                    c if item_start && is_ident(c) => {
                        item_start = false;
                        used.insert(word_at(&group[i..]));
                    }
                    _ => {}
                }
            }
        } else {
            used.insert(word_at(rest));
        }
    }
    for (at, _) in code.match_indices("super::") {
        if at > 0 {
            let before = code[..at].chars().next_back().unwrap();
            if is_ident(before) || before == ':' {
                continue;
            }
        }
        let mut rest = &code[at..];
        let mut up = 0;
        while let Some(r) = rest.strip_prefix("super::") {
            up += 1;
            rest = r;
        }
        if up < path.len() {
            // Still inside the file's own top-level module.
            continue;
        }
        if up == path.len() {
            used.insert(word_at(rest));
        }
    }
    used
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn modules_use_only_their_own_layer_or_lower_ones() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let src = root.join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut upward = BTreeSet::new();
    let mut unknown = Vec::new();
    for file in &files {
        let relative = file.strip_prefix(&src).unwrap();
        let path = module_path(relative);
        let Some(top) = path.first() else { continue };
        if top == "bin" {
            continue;
        }
        let Some(own) = layer_of(top) else {
            unknown.push(format!("{} (module {top})", relative.display()));
            continue;
        };
        let code = strip(&std::fs::read_to_string(file).unwrap());
        let name = format!("src/{}", relative.to_string_lossy().replace('\\', "/"));
        for used in used_modules(&code, &path) {
            if used == *top {
                continue;
            }
            if let Some(layer) = layer_of(&used) {
                if layer > own {
                    upward.insert((name.clone(), used));
                }
            }
        }
    }
    assert!(
        unknown.is_empty(),
        "top-level modules missing from LAYERS (add them here and to ARCHITECTURE.md): {unknown:?}"
    );
    let known: BTreeSet<(String, String)> = KNOWN_UPWARD
        .iter()
        .map(|(f, m, _)| (f.to_string(), m.to_string()))
        .collect();
    let new: Vec<_> = upward.difference(&known).collect();
    assert!(
        new.is_empty(),
        "upward uses across the layers of ARCHITECTURE.md (file, module used): {new:?}"
    );
    let gone: Vec<_> = known.difference(&upward).collect();
    assert!(
        gone.is_empty(),
        "KNOWN_UPWARD lists uses that no longer exist: remove them: {gone:?}"
    );
}

/// The checker itself: it sees `crate::` paths, groups and `super::` paths that leave the
/// top-level module, and ignores comments and strings.
#[test]
fn the_checker_finds_what_it_must() {
    let path = vec!["light".to_string(), "environment".to_string()];
    let code = strip(
        "use crate::film::Film;\n\
         use crate::{math::Rgb, scene::Scene};\n\
         // use crate::capi::Commented;\n\
         /* crate::render::Blocked */\n\
         let s = \"crate::compare::InAString\";\n\
         let x = crate::integrator::View::new();\n\
         use super::super::guide::Guide;\n\
         use super::sampler::Inside;\n",
    );
    let used = used_modules(&code, &path);
    let expected: BTreeSet<String> = ["film", "math", "scene", "integrator", "guide"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert_eq!(used, expected);
}
