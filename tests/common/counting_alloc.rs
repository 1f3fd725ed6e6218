//! The one counting allocator of the test crates: every allocation, zeroed allocation and
//! reallocation and every free is counted **per thread** (for the no-allocation tests: tests
//! running in parallel on other threads do not disturb each other's count), and the heap bytes
//! in use by the **whole process**, their peak since the last [`reset_peak`] and the process's
//! allocations are tracked (for the memory-bound tests: those see every thread, so a test
//! binary that measures them runs its memory tests one at a time, see [`process_exclusive`]).
//! A test crate installs it with `#[global_allocator] static GLOBAL: Counting = Counting;`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};

/// Counts the heap operations (per thread and per process), then forwards to the system
/// allocator.
pub struct Counting;

thread_local! {
    // Const-initialised, no destructor: touching them from the allocator cannot allocate,
    // and `try_with` keeps a thread's last frees during its teardown harmless.
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
    static FREES: Cell<u64> = const { Cell::new(0) };
}

static IN_USE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static PROCESS_ALLOCS: AtomicU64 = AtomicU64::new(0);

fn counted_alloc(size: usize) {
    let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
    PROCESS_ALLOCS.fetch_add(1, Ordering::Relaxed);
    grew(size);
}

fn grew(by: usize) {
    let now = IN_USE.fetch_add(by, Ordering::Relaxed) + by;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

// SAFETY: every call is forwarded unchanged to the system allocator; counting touches only
// thread-local `Cell`s and atomics (no allocation, no lock).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as our caller's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            counted_alloc(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as our caller's.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            counted_alloc(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as our caller's.
        unsafe { System.dealloc(ptr, layout) };
        let _ = FREES.try_with(|c| c.set(c.get() + 1));
        IN_USE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: same contract as our caller's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
            PROCESS_ALLOCS.fetch_add(1, Ordering::Relaxed);
            if new_size >= layout.size() {
                grew(new_size - layout.size());
            } else {
                IN_USE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

/// Allocations and reallocations on this thread so far.
pub fn allocations() -> u64 {
    ALLOCS.with(Cell::get)
}

/// Allocations, reallocations and frees on this thread so far (nothing may be freed on the
/// control thread either).
pub fn heap_ops() -> u64 {
    allocations() + FREES.with(Cell::get)
}

/// Heap bytes in use by the process now.
pub fn in_use() -> usize {
    IN_USE.load(Ordering::Relaxed)
}

/// The most heap bytes in use by the process since the last [`reset_peak`].
pub fn peak() -> usize {
    PEAK.load(Ordering::Relaxed)
}

/// Start a new peak from the bytes in use now.
pub fn reset_peak() {
    PEAK.store(in_use(), Ordering::Relaxed);
}

/// Allocations and reallocations of the whole process so far.
pub fn process_allocations() -> u64 {
    PROCESS_ALLOCS.load(Ordering::Relaxed)
}

/// Held by a test that measures the process-wide figures ([`in_use`], [`peak`],
/// [`process_allocations`]) for as long as it measures: the other such tests of its binary
/// wait (a panicked holder does not block the rest).
pub fn process_exclusive() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}
