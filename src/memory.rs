//! The memory budget: one resource model for every reader and every command.
//!
//! Sizes a file or a flag declares (cells × channels, payload lengths, sample and pair counts)
//! are turned into bytes and checked against one budget *before* anything of that size is
//! allocated, so a 1 KB header that claims 2³¹ cells, or a grid inside the documented limits
//! that would need 10 GB, is refused at once with the memory it would need (exit 2) instead
//! of aborting in the allocator (exit 134) or swapping for minutes.
//!
//! The budget is `--max-memory` (a global flag), else the `BRDFPACK_MAX_MEMORY` environment
//! variable, else [`DEFAULT_BUDGET`] (2 GiB: a fixed number, so a command is accepted or
//! refused the same way on every machine; a 64⁴ RGB table is 200 MB, MERL 17 MB).
//! docs/robustness.md lists what each command counts.

use crate::{Error, Result};
use std::sync::atomic::{AtomicU64, Ordering};

/// Default budget when neither the flag nor the environment sets one.
pub const DEFAULT_BUDGET: u64 = 2 << 30;
/// Name of the environment variable that sets the budget.
pub const ENV: &str = "BRDFPACK_MAX_MEMORY";
/// Copies of its largest table a command may hold at once: the table, its encoded bytes or
/// a decoding scratch, and a decoded copy to check (pack, compress, convert).
pub const WORKING_COPIES: u64 = 3;

/// 0 = not set by the flag (the environment or the default applies).
static BUDGET: AtomicU64 = AtomicU64::new(0);

/// Sets the budget for this process (the `--max-memory` flag).
pub fn set_budget(bytes: u64) {
    BUDGET.store(bytes.max(1), Ordering::Relaxed);
}

/// The budget in bytes: the flag, else `BRDFPACK_MAX_MEMORY`, else [`DEFAULT_BUDGET`].
/// An unparsable environment value is reported by [`budget_from_env`] at startup; here it
/// falls back to the default.
pub fn budget() -> u64 {
    match BUDGET.load(Ordering::Relaxed) {
        0 => budget_from_env().ok().flatten().unwrap_or(DEFAULT_BUDGET),
        b => b,
    }
}

/// The budget the environment sets, if any; an error names the variable and its value.
pub fn budget_from_env() -> Result<Option<u64>> {
    match std::env::var(ENV) {
        Ok(s) => parse_size(&s)
            .map(Some)
            .map_err(|e| Error::input(format!("{ENV}={}: {e}", crate::text::sanitize(&s)))),
        Err(_) => Ok(None),
    }
}

/// Parses a size: bytes, or a number with a unit `K`, `M`, `G`, `T` (powers of 1024; `KiB`,
/// `MB`, `GiB`... are read the same way).
pub fn parse_size(s: &str) -> Result<u64> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        other => {
            return Err(Error::input(format!(
                "memory size {t:?}: unknown unit {other:?} (use K, M, G or T)"
            )));
        }
    };
    let x: f64 = num
        .parse()
        .map_err(|_| Error::input(format!("memory size {t:?}: not a number")))?;
    let bytes = x * (1u64 << shift) as f64;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(Error::input(format!(
            "memory size {t:?}: out of range (1 byte to 16 EiB)"
        )));
    }
    Ok(bytes as u64)
}

/// A byte count for people: `1.5 GiB`, `17.5 MiB`, `512 B`.
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut x = bytes as f64;
    let mut u = 0;
    while x >= 1024.0 && u + 1 < UNITS.len() {
        x /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} B")
    } else {
        format!("{x:.1} {}", UNITS[u])
    }
}

/// Refuses work that needs more than the budget: `what` needs `bytes`.
pub fn require(what: &str, bytes: u64) -> Result<()> {
    let b = budget();
    if bytes > b {
        return Err(Error::input(format!(
            "{what} needs about {} of memory, more than the budget of {} (raise it with \
             --max-memory or {ENV})",
            human(bytes),
            human(b)
        )));
    }
    Ok(())
}

/// Bytes of one table of `cells` × `channels` in memory: f32 samples and a validity flag.
pub fn table_bytes(cells: usize, channels: usize) -> u64 {
    (cells as u64).saturating_mul((channels as u64).saturating_mul(4).saturating_add(1))
}

/// Checks that a command may hold [`WORKING_COPIES`] of a `cells` × `channels` table.
pub fn require_table(what: &str, cells: usize, channels: usize) -> Result<()> {
    require(
        what,
        table_bytes(cells, channels).saturating_mul(WORKING_COPIES),
    )
}

/// Bytes of `n` direction pairs held with their values: two f64 unit vectors (48 bytes)
/// and the values of a candidate and a reference at 3 channels in f64 (48 bytes).
pub fn pair_bytes(n: usize) -> u64 {
    (n as u64).saturating_mul(96)
}

/// Most worker threads a run may start (`RAYON_NUM_THREADS`, `bench --threads`): thousands
/// of threads on a few cores cost minutes of scheduling for a millisecond's work (issue 20:
/// `RAYON_NUM_THREADS=5000` made a 288-cell tabulation take 4 minutes).
pub const MAX_THREADS: usize = 1024;

/// Refuses a `RAYON_NUM_THREADS` above [`MAX_THREADS`]. Values rayon itself ignores (not a
/// number, 0 = one thread per core) are left to it.
pub fn check_thread_env() -> Result<()> {
    if let Ok(s) = std::env::var("RAYON_NUM_THREADS")
        && let Ok(n) = s.parse::<usize>()
        && n > MAX_THREADS
    {
        return Err(Error::input(format!(
            "RAYON_NUM_THREADS={n}: more than {MAX_THREADS} threads"
        )));
    }
    Ok(())
}

/// Starts the worker threads (rayon's global pool, `RAYON_NUM_THREADS` as rayon reads it)
/// before any work. Left to rayon's first parallel call, a thread the machine cannot start
/// (an address-space limit, `ulimit -v 65536`, refuses its stack) was a panic, exit 101;
/// now an error (exit 1). A pool already built (a caller of the library) is kept.
pub fn start_worker_threads() -> Result<()> {
    match rayon::ThreadPoolBuilder::new().build_global() {
        Ok(()) => Ok(()),
        Err(e) => {
            // The only other failure is a pool built before: nothing to do then.
            if rayon::current_num_threads() > 0 && e.to_string().contains("already") {
                return Ok(());
            }
            Err(Error::Failure(format!(
                "out of memory: the worker threads could not be started ({e}); no file written \
                 (the address-space limit, `ulimit -v`, or the machine's memory is too small: \
                 try RAYON_NUM_THREADS=1)"
            )))
        }
    }
}

std::thread_local! {
    static FALLIBLE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with this thread's allocation failures left to the caller (`try_reserve`'s
/// `Err`), for an allocator that otherwise ends the process on one (the binary's: a clean
/// exit 1 instead of Rust's abort, exit 134).
pub fn fallibly<R>(f: impl FnOnce() -> R) -> R {
    let before = FALLIBLE.with(|c| c.replace(true));
    let r = f();
    FALLIBLE.with(|c| c.set(before));
    r
}

/// True inside [`fallibly`] on this thread: an allocation that fails here is reported to its
/// caller. Allocation-free (an allocator may call it).
pub fn allocation_may_fail() -> bool {
    FALLIBLE.try_with(|c| c.get()).unwrap_or(false)
}

/// `vec![value; n]` that returns an error naming `what` instead of aborting when the
/// allocator refuses (the budget checks come first; this catches what they do not count).
pub fn try_filled<T: Clone>(n: usize, value: T, what: &str) -> Result<Vec<T>> {
    let mut v = Vec::new();
    fallibly(|| v.try_reserve_exact(n)).map_err(|_| {
        Error::Failure(format!(
            "{what}: could not allocate {}",
            human((n as u64).saturating_mul(std::mem::size_of::<T>() as u64))
        ))
    })?;
    advise_huge_pages(&v);
    v.resize(n, value);
    Ok(v)
}

/// Asks the kernel to back the 2 MiB-aligned part of a large, not yet written buffer with
/// transparent huge pages (Linux with THP in `madvise` or `always` mode). A decoded MERL-grid
/// table (17.5 MB) and its decoder's scratch were ~8,000 page faults of 4 KiB, a third of a
/// whole `brdfpack eval` process; with 2 MiB pages they are a few dozen. Advice only: where
/// the kernel declines or has no THP, nothing changes.
pub fn advise_huge_pages<T>(v: &Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = v.capacity().saturating_mul(std::mem::size_of::<T>());
        if bytes < 2 * HUGE {
            return;
        }
        let start = v.as_ptr() as usize;
        let first = start.next_multiple_of(HUGE);
        let end = (start + bytes) / HUGE * HUGE;
        if end > first {
            // SAFETY: [first, end) lies inside `v`'s allocation, which stays alive for the
            // call; MADV_HUGEPAGE changes how pages are backed, never their contents.
            unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = v;
}

/// Blocks of at least this size get a mapping of their own from glibc's allocator
/// ([`return_large_blocks`]).
pub const LARGE_BLOCK: usize = 8 << 20;

/// Makes glibc's allocator give every block of [`LARGE_BLOCK`] bytes or more a mapping of its
/// own, returned to the kernel when freed, for the whole process (the binary calls it at
/// start; a library caller decides for its own process). By default the threshold adapts:
/// it rises to the size of the largest block freed (up to 32 MiB), after which blocks of
/// several MB come from the heaps and stay resident when freed, and the heaps' free space
/// counts in the peak RSS. `pack` on the MERL grid peaked at ~131 MB RSS for a ~113 MB heap
/// with the adaptive threshold and at ~116 MB with this fixed one (the planner's stencils,
/// tables, planes and decode buffers are all above 8 MiB there; user + system time within
/// the run-to-run spread).
///
/// Setting the threshold also fixes glibc's trim threshold (the free space at the top of a
/// heap that `free` hands back at once) at its 128 KiB default: the rate control's per-trial
/// arrays below [`LARGE_BLOCK`] (a MERL-grid component's codes, 5.8 MB) were then returned
/// and faulted in again at every trial: 227,000–236,000 page faults and 0.46–0.50 s of
/// system time in a 2.2 s `pack` of the chrome-steel fit. It is set to [`KEPT_FREE`]:
/// 178,000 faults; `pack --max-error production` 2.16 → 2.07 s there, gold-metallic-paint
/// 1.60 → 1.51 s, a model on a log-space grid 1.49 → 1.39 s (medians of 3), peak RSS
/// +0.4–2 MB on MERL files and +17 MB (98 → 116 MB) for that model. The explicit trims before
/// the peaks ([`release_free_memory`]) still return everything. Elsewhere a no-op.
pub fn return_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's policy for later allocations.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LARGE_BLOCK as libc::c_int);
        libc::mallopt(libc::M_TRIM_THRESHOLD, KEPT_FREE as libc::c_int);
    }
}

/// Free space at the top of a heap that glibc keeps for reuse ([`return_large_blocks`]).
pub const KEPT_FREE: usize = 32 << 20;

/// Hands the allocator's free memory back to the kernel (glibc's `malloc_trim`), for a
/// caller that has just freed large transients and is about to reach its peak. glibc keeps
/// freed blocks below its adaptive mmap threshold (which rises to the size of the largest
/// block freed, up to 32 MiB) resident for reuse: in `pack` on the MERL grid the forward
/// DCT's planes and the colour transform's samples left ~20 MB resident beside the rate
/// control's buffers (peak RSS 137 MB against a 113 MB heap). Elsewhere a no-op.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's own heaps to the kernel;
    // no live allocation is touched.
    unsafe {
        libc::malloc_trim(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_size("512").unwrap(), 512);
        assert_eq!(parse_size("64K").unwrap(), 64 << 10);
        assert_eq!(parse_size("2GiB").unwrap(), 2 << 30);
        assert_eq!(parse_size("1.5 G").unwrap(), 3 << 29);
        assert!(parse_size("0").is_err());
        assert!(parse_size("-1G").is_err());
        assert!(parse_size("2 parsecs").is_err());
        assert!(parse_size("99999999T").is_err());
    }

    #[test]
    fn human_sizes_round_to_one_decimal() {
        assert_eq!(human(512), "512 B");
        assert_eq!(human(3 << 29), "1.5 GiB");
    }

    #[test]
    fn table_bytes_saturate_instead_of_wrapping() {
        assert_eq!(table_bytes(10, 3), 130);
        assert_eq!(table_bytes(usize::MAX, 4096), u64::MAX);
    }
}
