//! The heap the test bench allocates from: the thruster buses' model (lbv-sim's I2C bus: its wiring, and each
//! transfer's bytes while it is under way) and the ground station (lbv-station's: its frames, and the texts it
//! keeps). Nothing of the firmware allocates; the report gives the most they held at once.
// The global allocator's interface is unsafe by nature: it only forwards to embedded-alloc's.
#![allow(unsafe_code)]

use core::alloc::{GlobalAlloc, Layout};
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicUsize, Ordering::Relaxed};

use embedded_alloc::LlffHeap;

/// Its size: about four times the most a run holds at once (the report's `HEAP` line: 2.5 KiB in the vehicle run,
/// with three buses and six thrusters).
pub const HEAP_BYTES: usize = 10 * 1024;

/// embedded-alloc's first-fit heap, and the bytes allocated from it: now, and at most. Counted apart, so that
/// counting takes no critical section of its own (each one holds off the hall-edge interrupt).
struct Heap {
    heap: LlffHeap,
    used: AtomicUsize,
    peak: AtomicUsize,
}

#[global_allocator]
static HEAP: Heap = Heap {
    heap: LlffHeap::empty(),
    used: AtomicUsize::new(0),
    peak: AtomicUsize::new(0),
};

// SAFETY: every call forwards to embedded-alloc's allocator with the caller's own guarantees.
unsafe impl GlobalAlloc for Heap {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as the caller's.
        let block = unsafe { GlobalAlloc::alloc(&self.heap, layout) };
        if !block.is_null() {
            let size = layout.size();
            let used = self.used.fetch_add(size, Relaxed).saturating_add(size);
            self.peak.fetch_max(used, Relaxed);
        }
        block
    }

    unsafe fn dealloc(&self, block: *mut u8, layout: Layout) {
        // SAFETY: as the caller's: `block` came from `alloc` with `layout`.
        unsafe { GlobalAlloc::dealloc(&self.heap, block, layout) };
        self.used.fetch_sub(layout.size(), Relaxed);
    }
}

/// Give the heap its memory; before anything allocates, once.
pub fn init() {
    static mut MEMORY: [MaybeUninit<u8>; HEAP_BYTES] = [MaybeUninit::uninit(); HEAP_BYTES];
    // SAFETY: called once, first thing in thread mode, before any allocation; nothing else names `MEMORY`.
    unsafe { HEAP.heap.init(&raw mut MEMORY as usize, HEAP_BYTES) }
}

/// The most the heap has had allocated at once so far, bytes.
pub fn peak() -> usize {
    HEAP.peak.load(Relaxed)
}
