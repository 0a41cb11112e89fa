//! The files a command read (sources, `@spec.json` model files, optical-constant CSVs,
//! manifests), collected as they are opened and passed along by the caller (no global
//! state), and written as a Make/Ninja depfile (`--depfile`).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Paths read, as they were named (a relative name stays relative), sorted and unique.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReadSet {
    paths: BTreeSet<PathBuf>,
}

impl ReadSet {
    pub fn new() -> ReadSet {
        ReadSet::default()
    }

    /// Records a file read; stdin (`-`) is no file a build system can track.
    pub fn record(&mut self, path: impl AsRef<Path>) {
        let path = path.as_ref();
        if path.as_os_str() != "-" && !path.as_os_str().is_empty() {
            self.paths.insert(path.to_path_buf());
        }
    }

    pub fn extend(&mut self, other: &ReadSet) {
        self.paths.extend(other.paths.iter().cloned());
    }

    pub fn paths(&self) -> impl Iterator<Item = &Path> {
        self.paths.iter().map(PathBuf::as_path)
    }

    pub fn len(&self) -> usize {
        self.paths.len()
    }

    pub fn is_empty(&self) -> bool {
        self.paths.is_empty()
    }
}

/// A depfile in the syntax Make and Ninja (`deps = gcc`) read: `target...: dep...`, with
/// spaces, `#` and `:` in names escaped by a backslash and `$` doubled.
pub fn depfile_text<'a>(targets: impl IntoIterator<Item = &'a Path>, reads: &ReadSet) -> String {
    let targets: Vec<String> = targets.into_iter().map(escape).collect();
    let mut s = targets.join(" ");
    s.push(':');
    for p in reads.paths() {
        s.push_str(" \\\n  ");
        s.push_str(&escape(p));
    }
    s.push('\n');
    s
}

/// One path in depfile syntax.
fn escape(path: &Path) -> String {
    let mut out = String::new();
    for ch in path.to_string_lossy().chars() {
        match ch {
            ' ' | '#' | '\\' | ':' if ch != ':' || !cfg!(windows) => {
                out.push('\\');
                out.push(ch);
            }
            '$' => out.push_str("$$"),
            _ => out.push(ch),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depfile_escapes_and_keeps_relative_names() {
        let mut r = ReadSet::new();
        r.record("data/my gold.binary");
        r.record("spec.json");
        r.record("-");
        r.record("spec.json");
        let text = depfile_text([Path::new("out dir/a.bpk")], &r);
        assert_eq!(
            text,
            "out\\ dir/a.bpk: \\\n  data/my\\ gold.binary \\\n  spec.json\n"
        );
    }

    #[test]
    fn dollar_is_doubled() {
        let mut r = ReadSet::new();
        r.record("a$b.csv");
        assert_eq!(depfile_text([Path::new("t")], &r), "t: \\\n  a$$b.csv\n");
    }
}
