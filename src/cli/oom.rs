//! The binary's allocator: the system's, except that a failed allocation ends the process
//! with a `brdfpack:` line and exit 1 (a failure, not bad input) instead of Rust's abort
//! (exit 134, "memory allocation of N bytes failed" and a core dump), after removing the
//! temporary output files, so that nothing is written. Inside [`crate::memory::fallibly`]
//! (the readers' `try_reserve` of declared sizes) the failure is returned to the caller,
//! which reports it as its own error.

use std::alloc::{GlobalAlloc, Layout, System};

pub struct ExitOnOutOfMemory;

#[global_allocator]
static ALLOCATOR: ExitOnOutOfMemory = ExitOnOutOfMemory;

// SAFETY: every call is forwarded to `System` unchanged; only a null result is acted on.
unsafe impl GlobalAlloc for ExitOnOutOfMemory {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract, forwarded.
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            out_of_memory(new_size);
        }
        p
    }
}

/// Ends the process after a failed allocation of `size` bytes, unless the caller asked to
/// handle it. Neither allocates nor takes a lock: the message is built on the stack and
/// written with `write(2)`, the temporary files are unlinked, and `_exit` skips destructors
/// and stdio buffers (a partial report is not flushed).
fn out_of_memory(size: usize) {
    if crate::memory::allocation_may_fail() {
        return;
    }
    let mut msg = [0u8; 320];
    let mut n = 0;
    let mut put = |b: &[u8]| {
        let k = b.len().min(msg.len() - n);
        msg[n..n + k].copy_from_slice(&b[..k]);
        n += k;
    };
    put(b"brdfpack: out of memory: an allocation of ");
    let mut digits = [0u8; 20];
    let mut i = digits.len();
    let mut v = size;
    loop {
        i -= 1;
        digits[i] = b'0' + (v % 10) as u8;
        v /= 10;
        if v == 0 {
            break;
        }
    }
    put(&digits[i..]);
    put(
        b" bytes failed; no file written (the address-space limit, `ulimit -v`, or the \
          machine's memory is too small for this command: ask for less, e.g. a coarser \
          --grid or fewer --samples)\n",
    );
    crate::io::cleanup::remove_registered_files();
    #[cfg(unix)]
    // SAFETY: write(2) of a stack buffer and _exit are async-signal-safe and allocate nothing.
    unsafe {
        libc::write(2, msg.as_ptr().cast(), n);
        libc::_exit(1);
    }
    #[cfg(not(unix))]
    std::process::exit(1);
}
