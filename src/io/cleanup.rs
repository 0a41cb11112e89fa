//! Removing temporary output files when the process is killed by SIGINT, SIGTERM or SIGHUP
//! (Ctrl-C, `kill`, a closed terminal) or SIGXFSZ (a write past `ulimit -f`), so an
//! interrupted run leaves nothing behind.
//!
//! A signal handler may only call async-signal-safe functions: no locks, no allocation. The
//! temporary names live in a fixed array of atomic pointers to C strings; the handler
//! unlinks each registered name, restores the default action and re-raises the signal, so
//! the process still dies by it (exit status 128 + n for the shell). `libc` gives
//! `sigaction`, `unlink` and `raise`; std has no signal API.

use std::path::Path;

/// Temporary files registered at once (one per output being written; commands write one).
#[cfg(unix)]
const SLOTS: usize = 16;

#[cfg(unix)]
static TEMPS: [std::sync::atomic::AtomicPtr<libc::c_char>; SLOTS] =
    [const { std::sync::atomic::AtomicPtr::new(std::ptr::null_mut()) }; SLOTS];

/// A registered temporary file; dropping it unregisters the name (the caller has renamed or
/// removed the file by then).
pub struct Registered {
    #[cfg(unix)]
    slot: Option<usize>,
}

/// Registers `tmp` for removal if a terminating signal arrives before the guard is dropped;
/// installs the handlers the first time. More than [`SLOTS`] temporary files at once are
/// written without the guarantee.
#[cfg(unix)]
pub fn register(tmp: &Path) -> Registered {
    use std::os::unix::ffi::OsStrExt;
    use std::sync::atomic::Ordering;
    install();
    let Ok(c) = std::ffi::CString::new(tmp.as_os_str().as_bytes()) else {
        return Registered { slot: None };
    };
    // Never freed: the handler may read a name at any moment, even while its slot is being
    // cleared, so a freed name could be read after free. A few bytes per output written.
    let ptr = c.into_raw();
    for (i, slot) in TEMPS.iter().enumerate() {
        if slot
            .compare_exchange(
                std::ptr::null_mut(),
                ptr,
                Ordering::SeqCst,
                Ordering::SeqCst,
            )
            .is_ok()
        {
            return Registered { slot: Some(i) };
        }
    }
    Registered { slot: None }
}

#[cfg(not(unix))]
pub fn register(_tmp: &Path) -> Registered {
    Registered {}
}

#[cfg(unix)]
impl Drop for Registered {
    fn drop(&mut self) {
        if let Some(i) = self.slot {
            TEMPS[i].store(std::ptr::null_mut(), std::sync::atomic::Ordering::SeqCst);
        }
    }
}

/// Removes every registered temporary file now, without allocating or taking a lock (safe
/// in a signal handler, or in an allocator that has just failed: the binary's
/// out-of-memory exit).
#[cfg(unix)]
pub fn remove_registered_files() {
    for slot in &TEMPS {
        let p = slot.load(std::sync::atomic::Ordering::SeqCst);
        if !p.is_null() {
            // SAFETY: `p` is a NUL-terminated name that is never freed; unlink is
            // async-signal-safe.
            unsafe {
                libc::unlink(p);
            }
        }
    }
}

#[cfg(not(unix))]
pub fn remove_registered_files() {}

#[cfg(unix)]
extern "C" fn on_signal(sig: libc::c_int) {
    remove_registered_files();
    // SAFETY: signal and raise are async-signal-safe.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
        libc::raise(sig);
    }
}

#[cfg(unix)]
fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP, libc::SIGXFSZ] {
            // SAFETY: plain sigaction calls on zero-initialised C structs.
            unsafe {
                let mut old: libc::sigaction = std::mem::zeroed();
                if libc::sigaction(sig, std::ptr::null(), &mut old) != 0 {
                    continue;
                }
                // An ignored signal (`nohup`, a shell's background job) stays ignored; a
                // handler someone else installed is left alone.
                if old.sa_sigaction != libc::SIG_DFL {
                    continue;
                }
                let mut act: libc::sigaction = std::mem::zeroed();
                act.sa_sigaction = on_signal as *const () as libc::sighandler_t;
                libc::sigemptyset(&mut act.sa_mask);
                act.sa_flags = 0;
                libc::sigaction(sig, &act, std::ptr::null_mut());
            }
        }
    });
}
