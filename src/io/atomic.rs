//! Reading inputs (a path or `-` for stdin) and writing outputs atomically: a temporary file
//! in the target directory, flushed and synced, then renamed over the target, so an
//! interrupted or failed run leaves any previous file intact and never a partial one.

use crate::{Error, Result};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Largest input read into memory (a MERL file is 35 MB; a 64⁴ RGB f32 table 200 MB); the
/// memory budget (`--max-memory`) lowers it.
pub const MAX_INPUT_BYTES: u64 = 8 << 30;
/// Bytes of a stream read before its format is recognised (or refused).
const SNIFF_BYTES: usize = 64 << 10;

/// Reads a whole input: a file, or stdin for `-`. A regular file's size is checked against
/// the memory budget before it is read; a stream (stdin, a FIFO, a device such as
/// `/dev/zero`) must start like a known format, so an endless one is refused after 64 KiB.
pub fn read_input(path: &Path) -> Result<Vec<u8>> {
    let limit = MAX_INPUT_BYTES.min(crate::memory::budget());
    if path.as_os_str() == "-" {
        return read_stream(&mut std::io::stdin().lock(), path, limit);
    }
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = f.metadata().map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::invalid_file(path, "is a directory, not a file"));
    }
    if !meta.is_file() {
        return read_stream(&mut f, path, limit);
    }
    if meta.len() > limit {
        return Err(Error::invalid_file(
            path,
            format!(
                "{} bytes: reading it needs {}, more than the input limit of {} (the memory \
                 budget; raise it with --max-memory or {})",
                meta.len(),
                crate::memory::human(meta.len()),
                crate::memory::human(limit),
                crate::memory::ENV
            ),
        ));
    }
    let mut buf = Vec::new();
    crate::memory::fallibly(|| buf.try_reserve_exact(meta.len() as usize))
        .map_err(|_| Error::Failure(format!("{}: out of memory", path.display())))?;
    f.take(limit + 1)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    too_large(path, &buf, limit)?;
    Ok(buf)
}

fn too_large(path: &Path, buf: &[u8], limit: u64) -> Result<()> {
    if buf.len() as u64 > limit {
        return Err(Error::invalid_file(
            path,
            format!(
                "larger than the input limit of {} (the memory budget; raise it with \
                 --max-memory or {})",
                crate::memory::human(limit),
                crate::memory::ENV
            ),
        ));
    }
    Ok(())
}

/// Reads a stream whose length is unknown: its first bytes must be those of a known input
/// format (a MERL header also fixes the length), else it is refused without reading on.
fn read_stream(r: &mut dyn Read, path: &Path, limit: u64) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    r.take(SNIFF_BYTES as u64)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    if buf.len() < SNIFF_BYTES {
        return Ok(buf); // the whole input; the decoder judges it
    }
    let limit = match stream_length(&buf) {
        Some(StreamKind::Sized(n)) => n.min(limit),
        Some(StreamKind::Unsized) => limit,
        None => {
            return Err(Error::invalid_file(
                path,
                "its first bytes are not those of a brdfpack table, EXR, MERL or RGL file \
                 (refused without reading on: it is a stream of unknown length)",
            ));
        }
    };
    r.take(limit + 1 - buf.len() as u64)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    too_large(path, &buf, limit)?;
    Ok(buf)
}

enum StreamKind {
    /// The header fixes the total length.
    Sized(u64),
    Unsized,
}

fn stream_length(head: &[u8]) -> Option<StreamKind> {
    if crate::io::native::is_native(head)
        || crate::io::exr::is_exr(head)
        || head.starts_with(b"tensor_file")
    {
        return Some(StreamKind::Unsized);
    }
    // MERL: three positive i32 bin counts, then 3 × 8 bytes per bin.
    let mut n: u64 = 1;
    for k in 0..3 {
        let v = i32::from_le_bytes(head[4 * k..4 * k + 4].try_into().ok()?);
        if v <= 0 || v as usize > crate::grid::MAX_AXIS_RESOLUTION {
            return None;
        }
        n *= v as u64;
    }
    Some(StreamKind::Sized(12 + 24 * n))
}

/// Set by the global `--force-terminal` flag: binary output may go to a terminal.
static BINARY_TO_TERMINAL: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// Allows [`write_output`] to write to stdout when it is a terminal.
pub fn allow_binary_to_terminal(yes: bool) {
    BINARY_TO_TERMINAL.store(yes, std::sync::atomic::Ordering::Relaxed);
}

/// Writes `bytes` to `path`, or to stdout for `-`.
///
/// - A regular file (or a name that does not exist yet) is written atomically: a temporary
///   file with a random name beside the target, synced, then renamed over it. The previous
///   file is intact until the rename; the temporary file is removed on failure and on
///   SIGINT, SIGTERM and SIGHUP; a leftover temporary file never blocks a run. An existing
///   file's permission bits are kept.
/// - A symlink is followed: the file it points to is replaced, the link stays.
/// - Anything else (`/dev/null`, a FIFO, a terminal, `/dev/stdout`, `/dev/fd/N`) is opened
///   and written in place: it cannot be replaced by renaming.
/// - A directory, or a name ending in `/`, is an input error (exit 2).
/// - Stdout that is a terminal is refused unless `--force-terminal` was given.
pub fn write_output(path: &Path, bytes: &[u8]) -> Result<()> {
    if path.as_os_str() == "-" {
        if std::io::IsTerminal::is_terminal(&std::io::stdout())
            && !BINARY_TO_TERMINAL.load(std::sync::atomic::Ordering::Relaxed)
        {
            return Err(Error::input(
                "-o -: stdout is a terminal; redirect it to a file or a pipe, or pass \
                 --force-terminal to print the binary output anyway",
            ));
        }
        let mut out = std::io::stdout().lock();
        out.write_all(bytes)
            .and_then(|_| out.flush())
            .map_err(|e| Error::io("<stdout>", e))?;
        return Ok(());
    }
    match output_target(path)? {
        Target::InPlace => {
            let mut f = std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map_err(|e| Error::io(path, e))?;
            f.write_all(bytes)
                .and_then(|_| f.flush())
                .map_err(|e| Error::io(path, e))
        }
        Target::Replace { file, permissions } => replace(path, &file, bytes, permissions),
    }
}

enum Target {
    /// A device, FIFO, socket or `/dev/fd` name: opened and written, never renamed over.
    InPlace,
    /// A regular file (existing or new) at `file`, the end of any symlinks.
    Replace {
        file: PathBuf,
        permissions: Option<std::fs::Permissions>,
    },
}

/// What writing to `path` means; see [`write_output`].
fn output_target(path: &Path) -> Result<Target> {
    let s = path.as_os_str().to_string_lossy();
    if s.ends_with('/') {
        return Err(Error::input(format!(
            "-o {}: names a directory (ends with /); give a file name",
            path.display()
        )));
    }
    // /dev/stdout, /dev/fd/1, /proc/self/fd/1: the file behind a descriptor is written in
    // place whatever it is (renaming over it would detach the caller's descriptor).
    if s.starts_with("/dev/") || s.starts_with("/proc/") {
        return match std::fs::metadata(path) {
            Ok(m) if m.is_dir() => Err(is_a_directory(path)),
            Ok(_) => Ok(Target::InPlace),
            Err(e) => Err(Error::io(path, e)),
        };
    }
    let file = resolve_symlinks(path)?;
    match std::fs::metadata(&file) {
        Ok(m) if m.is_dir() => Err(is_a_directory(path)),
        Ok(m) if !m.is_file() => Ok(Target::InPlace),
        Ok(m) => Ok(Target::Replace {
            file,
            permissions: Some(m.permissions()),
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let dir = file.parent().filter(|p| !p.as_os_str().is_empty());
            if let Some(d) = dir
                && !d.is_dir()
            {
                return Err(Error::input(format!(
                    "{}: directory {} does not exist",
                    path.display(),
                    d.display()
                )));
            }
            Ok(Target::Replace {
                file,
                permissions: None,
            })
        }
        Err(e) => Err(Error::io(path, e)),
    }
}

fn is_a_directory(path: &Path) -> Error {
    Error::input(format!(
        "-o {}: is a directory; give a file name inside it",
        path.display()
    ))
}

/// The end of the chain of symlinks starting at `path` (the path itself when it is none);
/// works for a dangling link too, whose target is then created.
fn resolve_symlinks(path: &Path) -> Result<PathBuf> {
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let target = std::fs::read_link(&p).map_err(|e| Error::io(path, e))?;
                p = match p.parent() {
                    Some(dir) if target.is_relative() => dir.join(target),
                    _ => target,
                };
            }
            _ => return Ok(p),
        }
    }
    Err(Error::input(format!(
        "{}: too many levels of symbolic links",
        path.display()
    )))
}

/// Writes `bytes` to a fresh temporary file beside `file`, then renames it over `file`.
fn replace(
    shown: &Path,
    file: &Path,
    bytes: &[u8],
    permissions: Option<std::fs::Permissions>,
) -> Result<()> {
    let (tmp, mut f) = create_temp(shown, file)?;
    let guard = crate::io::cleanup::register(&tmp);
    let result = (|| -> std::io::Result<()> {
        if let Some(p) = permissions {
            f.set_permissions(p)?;
        }
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, file)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        drop(guard);
        return Err(Error::io(shown, e));
    }
    drop(guard);
    Ok(())
}

/// Longest file name most file systems take (bytes).
const MAX_NAME_BYTES: usize = 255;

/// Creates a temporary file with a random name beside `file` (same directory, so the
/// rename is atomic): `.NAME.RANDOM.tmp`, NAME cut so the whole fits in 255 bytes. A name
/// that exists (a leftover of a killed run, another process) is skipped, not an error.
fn create_temp(shown: &Path, file: &Path) -> Result<(PathBuf, std::fs::File)> {
    let name = file
        .file_name()
        .ok_or_else(|| Error::input(format!("{}: not a file path", shown.display())))?;
    if name.len() > MAX_NAME_BYTES {
        return Err(Error::input(format!(
            "{}: the file name is {} bytes long, more than {MAX_NAME_BYTES}",
            shown.display(),
            name.len()
        )));
    }
    let name = name.to_string_lossy();
    // 1 + name + 1 + 16 hex digits + 4 (".tmp") bytes.
    let mut keep = name.len().min(MAX_NAME_BYTES - 22);
    while !name.is_char_boundary(keep) {
        keep -= 1;
    }
    let dir = file.parent().filter(|p| !p.as_os_str().is_empty());
    for _ in 0..64 {
        let tmp_name = format!(".{}.{:016x}.tmp", &name[..keep], random_u64());
        let tmp = match dir {
            Some(d) => d.join(tmp_name),
            None => PathBuf::from(tmp_name),
        };
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
        {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(Error::io(shown, e)),
        }
    }
    Err(Error::Failure(format!(
        "{}: no free temporary name after 64 tries",
        shown.display()
    )))
}

/// 64 random bits: std's hasher keys come from the OS's random source once per process;
/// the process id, the time and a counter make every call differ.
fn random_u64() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.write_u64(COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed));
    if let Ok(t) = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH) {
        h.write_u128(t.as_nanos());
    }
    h.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_replace_atomically_and_leave_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.bin");
        write_output(&p, b"first").unwrap();
        write_output(&p, b"second").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"second");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn missing_directory_is_an_input_error() {
        let e = write_output(Path::new("/nonexistent-dir/x.bpk"), b"x").unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("does not exist"));
    }
}
