//! Issue #24: one direction of dependency. Reads every `src/**/*.rs`, finds the crate paths it
//! uses (`crate::a::b`, `use crate::{a, b::c}`, `super::x`), places each file and each path in
//! the layer table below (longest module prefix wins) and fails when a file uses a layer above
//! its own. Test code (`#[cfg(test)]` items) may use any layer, like a dev-dependency. Also:
//! `clap` and `indicatif` only in the binary (`src/main.rs`, `src/cli/`), and optional in
//! Cargo.toml behind the `cli` feature.
//!
//! ARCHITECTURE.md shows the same table with one line per module; keep them together.

use std::path::{Path, PathBuf};

/// The layers, lowest first (numbered as in ARCHITECTURE.md): a module may use its own layer
/// and the ones before it in this list, never one after. Module paths are relative to the
/// crate root; "" is the root (`lib.rs`: `Error`, `Result`, `TOOL_VERSION`), `main` the
/// binary's root.
const LAYERS: &[&[&str]] = &[
    &["", "error"],
    &["text"],
    &["memory"],
    &["reads"],
    &["math"],
    &["simd"],
    &["geometry"],
    &["brdf"],
    &["spectral"],
    &["model"],
    &["grid"],
    &["table"],
    &["tabulate"],
    &["props"],
    &["check"],
    &["codec"],
    &["io"],
    &["source"],
    &["pairs"],
    &["plot"],
    &["plan"],
    &["bench"],
    &["testing"],
    &["cli", "main"],
];

/// Back-edges still present, as (file module, used module); each must still occur (so the
/// list only shrinks) and none may be added.
const KNOWN_BACK_EDGES: &[(&str, &str)] = &[];

/// The index of the layer holding `module` (longest prefix on `::` boundaries).
fn layer_of(module: &str) -> Option<usize> {
    let mut best: Option<(usize, usize)> = None;
    for (rank, prefix) in LAYERS
        .iter()
        .enumerate()
        .flat_map(|(rank, prefixes)| prefixes.iter().map(move |p| (rank, p)))
    {
        let hit = prefix.is_empty()
            || module == *prefix
            || (module.starts_with(prefix) && module[prefix.len()..].starts_with("::"));
        if hit && best.is_none_or(|(len, _)| prefix.len() > len) {
            best = Some((prefix.len(), rank));
        }
    }
    best.map(|(_, rank)| rank)
}

/// The name of a layer (its first module).
fn name(rank: usize) -> &'static str {
    let n = LAYERS[rank][0];
    if n.is_empty() { "lib" } else { n }
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// `src/a/b.rs` → `a::b`, `src/a/mod.rs` → `a`, `src/lib.rs` → ``, `src/main.rs` → `main`.
fn module_of(rel: &Path) -> String {
    let mut parts: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if parts.is_empty() && stem == "lib" {
        return String::new();
    }
    if stem != "mod" {
        parts.push(stem.to_string());
    }
    parts.join("::")
}

/// The text with comments removed and string/char literal contents blanked, so that only code
/// is searched. Newlines are kept (line numbers stay right).
fn code_only(src: &str) -> Vec<u8> {
    let b = src.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    let blank = |c: u8| if c == b'\n' { b'\n' } else { b' ' };
    while i < b.len() {
        let c = b[i];
        if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                out.push(b' ');
                i += 1;
            }
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                    depth += 1;
                    out.extend_from_slice(b"  ");
                    i += 2;
                } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                    depth -= 1;
                    out.extend_from_slice(b"  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    out.push(blank(b[i]));
                    i += 1;
                }
            }
        } else if c == b'r'
            && (b.get(i + 1) == Some(&b'"') || b.get(i + 1) == Some(&b'#'))
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'))
        {
            // Raw string r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                out.push(c);
                i += 1;
                continue;
            }
            out.extend(std::iter::repeat_n(b' ', j + 1 - i));
            i = j + 1;
            loop {
                if i >= b.len() {
                    break;
                }
                if b[i] == b'"' && (0..hashes).all(|h| b.get(i + 1 + h) == Some(&b'#')) {
                    out.extend(std::iter::repeat_n(b' ', 1 + hashes));
                    i += 1 + hashes;
                    break;
                }
                out.push(blank(b[i]));
                i += 1;
            }
        } else if c == b'"' {
            out.push(b' ');
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    out.push(b' ');
                    i += 1;
                }
                if i < b.len() {
                    out.push(blank(b[i]));
                    i += 1;
                }
            }
            out.push(b' ');
            i += 1;
        } else if c == b'\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a).
            if b.get(i + 1) == Some(&b'\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != b'\'' {
                    j += 1;
                }
                out.extend(std::iter::repeat_n(b' ', j + 1 - i));
                i = j + 1;
            } else if let Some(len) = std::str::from_utf8(&b[i + 1..(i + 6).min(b.len())])
                .ok()
                .or_else(|| std::str::from_utf8(&b[i + 1..]).ok())
                .and_then(|s| s.chars().next())
                .map(char::len_utf8)
                .filter(|&l| b.get(i + 1 + l) == Some(&b'\''))
            {
                out.extend(std::iter::repeat_n(b' ', len + 2));
                i += len + 2;
            } else {
                out.push(c);
                i += 1;
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

/// Blanks the items marked `#[cfg(test)]` (test modules and helpers).
fn without_test_items(code: &mut [u8]) {
    let pat = b"#[cfg(test)]";
    let mut i = 0;
    while i + pat.len() <= code.len() {
        if &code[i..i + pat.len()] != pat {
            i += 1;
            continue;
        }
        let start = i;
        let mut j = i + pat.len();
        // The item ends at the first `;` before any `{`, or at the `}` closing the first `{`.
        while j < code.len() && code[j] != b'{' && code[j] != b';' {
            j += 1;
        }
        if j < code.len() && code[j] == b'{' {
            let mut depth = 0;
            while j < code.len() {
                match code[j] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            break;
                        }
                    }
                    _ => {}
                }
                j += 1;
            }
        }
        let end = (j + 1).min(code.len());
        for c in &mut code[start..end] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
        i = end;
    }
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// Reads a path (idents joined by `::`, ending in a `{...}` group or `*`) starting at `i`;
/// pushes every full path (prefix + what follows) to `out`.
fn read_tree(code: &[u8], mut i: usize, prefix: &str, out: &mut Vec<String>) -> usize {
    let skip_ws = |mut i: usize| {
        while i < code.len() && code[i].is_ascii_whitespace() {
            i += 1;
        }
        i
    };
    let mut path = prefix.to_string();
    loop {
        i = skip_ws(i);
        if i < code.len() && code[i] == b'{' {
            i += 1;
            loop {
                i = skip_ws(i);
                if i >= code.len() {
                    return i;
                }
                if code[i] == b'}' {
                    return i + 1;
                }
                if code[i] == b',' {
                    i += 1;
                    continue;
                }
                let before = i;
                i = read_tree(code, i, &path, out);
                if i == before {
                    i += 1;
                }
            }
        }
        let start = i;
        while i < code.len() && is_ident(code[i]) {
            i += 1;
        }
        if i == start {
            // `*` or nothing: the path so far.
            out.push(path);
            return i;
        }
        let ident = std::str::from_utf8(&code[start..i]).unwrap();
        if !path.is_empty() {
            path.push_str("::");
        }
        path.push_str(ident);
        let k = skip_ws(i);
        if code.get(k) == Some(&b':') && code.get(k + 1) == Some(&b':') {
            i = k + 2;
        } else {
            // `self` in a group means the group's prefix.
            if let Some(p) = path.strip_suffix("::self") {
                path = p.to_string();
            }
            out.push(path);
            return i;
        }
    }
}

/// The crate modules a file's code names: `crate::` and `$crate::` paths, and `super::`
/// paths resolved against `module` (a `mod.rs` module is its directory).
fn used_paths(code: &[u8], module: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    let line_of = |i: usize| code[..i].iter().filter(|&&c| c == b'\n').count() + 1;
    let mut i = 0;
    while i < code.len() {
        if !is_ident(code[i]) || (i > 0 && (is_ident(code[i - 1]) || code[i - 1] == b':')) {
            i += 1;
            continue;
        }
        let start = i;
        while i < code.len() && is_ident(code[i]) {
            i += 1;
        }
        let word = std::str::from_utf8(&code[start..i]).unwrap();
        if (word != "crate" && word != "super") || code.get(i..i + 2) != Some(b"::") {
            continue;
        }
        if start > 0 && code[start - 1] == b'$' && word != "crate" {
            continue;
        }
        let base = if word == "crate" {
            String::new()
        } else {
            // super:: from a file module: its parent, one more for each further super::.
            let mut parts: Vec<&str> = module.split("::").filter(|s| !s.is_empty()).collect();
            parts.pop();
            while code.get(i..i + 9) == Some(b"::super::") {
                parts.pop();
                i += 7;
            }
            parts.join("::")
        };
        let mut paths = Vec::new();
        let end = read_tree(code, i + 2, &base, &mut paths);
        let line = line_of(start);
        for p in paths {
            found.push((line, p));
        }
        i = end.max(i + 2);
    }
    found
}

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The modules declared `#[cfg(test)] mod name;` in `code` (of module `parent`): files that
/// are test code as a whole, like a `#[cfg(test)] mod tests { .. }` block.
fn test_only_children(code: &[u8], parent: &str) -> Vec<String> {
    let pat = b"#[cfg(test)]";
    let mut out = Vec::new();
    let skip_ws = |mut i: usize| {
        while i < code.len() && code[i].is_ascii_whitespace() {
            i += 1;
        }
        i
    };
    for start in 0..code.len().saturating_sub(pat.len()) {
        if &code[start..start + pat.len()] != pat {
            continue;
        }
        let i = skip_ws(start + pat.len());
        if !code[i..].starts_with(b"mod")
            || code.get(i + 3).is_none_or(|c| !c.is_ascii_whitespace())
        {
            continue;
        }
        let i = skip_ws(i + 3);
        let mut j = i;
        while j < code.len() && is_ident(code[j]) {
            j += 1;
        }
        if j > i && code.get(skip_ws(j)) == Some(&b';') {
            let child = String::from_utf8_lossy(&code[i..j]).into_owned();
            // The binary's root declares crate-level modules of its own.
            out.push(match parent {
                "" | "main" => child,
                p => format!("{p}::{child}"),
            });
        }
    }
    out
}

/// Every use of a layer above the user's: "file:line: module (layer) uses path (layer)".
fn back_edges() -> (Vec<String>, Vec<(String, String)>) {
    let src = src_dir();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut report = Vec::new();
    let mut edges = Vec::new();
    let mut test_only = Vec::new();
    for f in &files {
        let module = module_of(f.strip_prefix(&src).unwrap());
        let code = code_only(&std::fs::read_to_string(f).unwrap());
        test_only.extend(test_only_children(&code, &module));
    }
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let module = module_of(rel);
        if test_only
            .iter()
            .any(|t| module == *t || module.starts_with(&format!("{t}::")))
        {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        let mut code = code_only(&text);
        without_test_items(&mut code);
        let Some(own) = layer_of(&module) else {
            report.push(format!(
                "src/{}: module `{module}` has no layer",
                rel.display()
            ));
            continue;
        };
        for (line, path) in used_paths(&code, &module) {
            let Some(used) = layer_of(&path) else {
                report.push(format!(
                    "src/{}:{line}: `{path}` has no layer",
                    rel.display()
                ));
                continue;
            };
            if used > own {
                let edge = (name(own).to_string(), name(used).to_string());
                if KNOWN_BACK_EDGES
                    .iter()
                    .any(|&(a, b)| (a, b) == (edge.0.as_str(), edge.1.as_str()))
                {
                    edges.push(edge);
                    continue;
                }
                report.push(format!(
                    "src/{}:{line}: `{module}` (layer {own} `{}`) uses `crate::{path}` (layer {used} `{}`)",
                    rel.display(),
                    name(own),
                    name(used),
                ));
                edges.push(edge);
            }
        }
    }
    (report, edges)
}

#[test]
fn no_module_uses_a_layer_above_it() {
    let (report, edges) = back_edges();
    let stale: Vec<_> = KNOWN_BACK_EDGES
        .iter()
        .filter(|&&(a, b)| !edges.iter().any(|e| (e.0.as_str(), e.1.as_str()) == (a, b)))
        .collect();
    assert!(
        report.is_empty() && stale.is_empty(),
        "the layer order (tests/layers.rs LAYERS, ARCHITECTURE.md) is broken:\n{}\n\
         known back-edges no longer present (remove them from KNOWN_BACK_EDGES): {stale:?}",
        report.join("\n")
    );
}

/// Below `io` nothing opens a file: physics, tables and codecs take text and bytes (model
/// specs name files through `model::SpecFiles`, read by `io::model_files`).
#[test]
fn no_file_access_below_io() {
    let io = layer_of("io").unwrap();
    let src = src_dir();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut report = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let module = module_of(rel);
        if layer_of(&module).is_none_or(|l| l >= io) {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        let mut code = code_only(&text);
        without_test_items(&mut code);
        let code = String::from_utf8(code).unwrap();
        for (n, line) in code.lines().enumerate() {
            if ["std::fs", "fs::", "File::", "OpenOptions"]
                .iter()
                .any(|p| line.contains(p))
            {
                report.push(format!("src/{}:{}: {}", rel.display(), n + 1, line.trim()));
            }
        }
    }
    assert!(
        report.is_empty(),
        "file access below io:\n{}",
        report.join("\n")
    );
}

/// The CLI's dependencies appear only in the binary's files.
#[test]
fn clap_and_indicatif_only_in_the_cli() {
    let src = src_dir();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut report = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        if rel.starts_with("cli") || rel == Path::new("main.rs") {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap();
        let code = String::from_utf8(code_only(&text)).unwrap();
        for (n, line) in code.lines().enumerate() {
            for dep in ["clap", "indicatif"] {
                let mut rest = line;
                while let Some(at) = rest.find(dep) {
                    let before = rest[..at].bytes().last();
                    let after = rest.as_bytes().get(at + dep.len()).copied();
                    let word = !before.is_some_and(is_ident) && !after.is_some_and(is_ident);
                    if word {
                        report.push(format!(
                            "src/{}:{}: {dep}: {}",
                            rel.display(),
                            n + 1,
                            line.trim()
                        ));
                    }
                    rest = &rest[at + dep.len()..];
                }
            }
        }
    }
    assert!(
        report.is_empty(),
        "CLI dependencies in the library:\n{}",
        report.join("\n")
    );
    // And in Cargo.toml: optional, enabled by the `cli` feature the binary requires.
    let toml =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml")).unwrap();
    for dep in ["clap", "clap_complete", "clap_mangen", "indicatif"] {
        let line = toml
            .lines()
            .find(|l| l.starts_with(&format!("{dep} = ")))
            .unwrap_or_else(|| panic!("Cargo.toml: no {dep}"));
        assert!(
            line.contains("optional = true"),
            "Cargo.toml: {dep} is not optional: {line}"
        );
    }
    assert!(
        toml.contains("required-features = [\"cli\"]"),
        "Cargo.toml: the binary does not require `cli`"
    );
}

/// The parser of this test: paths in groups, `super::`, comments and strings ignored, test
/// items skipped.
#[test]
fn the_path_reader_reads_what_it_should() {
    let src = "use crate::a::{b, c::{d, self}};\n\
               // crate::comment::x\n\
               let s = \"crate::string\";\n\
               fn f() { super::sib::g(); crate::Error::input(); }\n\
               #[cfg(test)]\nmod tests { use crate::up::x; }\n\
               let c = '\"'; x::<'a>(crate::after::y);\n";
    let mut code = code_only(src);
    without_test_items(&mut code);
    let paths: Vec<String> = used_paths(&code, "p::q")
        .into_iter()
        .map(|(_, p)| p)
        .collect();
    assert_eq!(
        paths,
        [
            "a::b",
            "a::c::d",
            "a::c",
            "p::sib::g",
            "Error::input",
            "after::y"
        ]
    );
    assert_eq!(name(layer_of("table::Table").unwrap()), "table");
    assert_eq!(name(layer_of("Error").unwrap()), "lib");
    assert_eq!(layer_of("error::Error"), layer_of("Error"));
    assert_eq!(name(layer_of("codec::simd::avx2").unwrap()), "codec");
    assert_eq!(layer_of("main"), layer_of("cli::common"));
    assert_eq!(module_of(Path::new("a/mod.rs")), "a");
    let decls = code_only("#[cfg(test)]\nmod tests;\nmod planes;\n#[cfg(test)] mod x { }\n");
    assert_eq!(test_only_children(&decls, "codec"), ["codec::tests"]);
    assert_eq!(test_only_children(&decls, ""), ["tests"]);
    assert_eq!(module_of(Path::new("a/b.rs")), "a::b");
}
