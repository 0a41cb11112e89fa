//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The reference material folder: `$BRDFPACK_SHARED`, else `../shared` beside the crate.
/// `None` in a user's clone, where tests that need it print a reason and pass.
pub fn shared_dir() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("BRDFPACK_SHARED") {
        // Set but absent: skip like a user's clone, rather than fail on missing files.
        return Some(PathBuf::from(p)).filter(|p| p.is_dir());
    }
    let sibling = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    sibling.is_dir().then_some(sibling)
}

/// A file under the shared folder, or `None` (with the skip reason printed).
pub fn shared_file(rel: &str) -> Option<PathBuf> {
    match shared_dir().map(|d| d.join(rel)) {
        Some(p) if p.exists() => Some(p),
        _ => {
            println!("skipped: ../shared/{rel} not found (set BRDFPACK_SHARED to run this test)");
            None
        }
    }
}
