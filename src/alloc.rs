//! The binary's allocator: the system's, keeping the last large block freed for the next
//! allocation of the same layout.
//!
//! A frame-sized buffer (a rectified 4400² RGB view is 58 MB) that is freed and allocated again
//! goes back to the kernel and comes back as fresh pages: each first touch is a page fault and a
//! kernel zeroing, and in a VM whose free memory is handed back to the host, a host fault as well.
//! That cost is 1.5-25 ms a frame on the 2-core VM (docs/benchmarks.md), as much as the warp
//! itself. glibc keeps freed blocks below its mmap threshold (at most 32 MiB) for reuse, not
//! larger ones; this keeps **one** freed block of 8 to 128 MiB whose size recurs (the large block
//! freed before it had the same size and alignment) and hands it to the next allocation of
//! exactly that layout, so a program that makes a frame-sized output per call pays the fresh
//! pages for its first two calls, not for each. Blocks of varying sizes (files read whole) are
//! returned at once, and any other large allocation first returns the kept block, so at most one
//! block is held beyond what the program holds, and only until the next large allocation.
//!
//! The `layerwise` binary, its benches and its examples use it (`#[global_allocator]`); a
//! program that links the library chooses its own.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;

/// Blocks at least this large are kept when freed (smaller ones glibc keeps itself).
pub const KEEP_FROM: usize = 8 << 20;
/// Blocks larger than this are returned at once (a CT volume is not held while idle).
pub const KEEP_UP_TO: usize = 128 << 20;

/// The system allocator, keeping the last large block freed (see the module).
pub struct LargeBlockCache {
    slot: Mutex<Slot>,
}

/// The block kept, and the layout of the last large block freed.
struct Slot {
    kept: Option<Kept>,
    last_freed: Option<Layout>,
}

/// A freed block and the layout it was allocated with.
struct Kept {
    ptr: usize,
    layout: Layout,
}

impl LargeBlockCache {
    pub const fn new() -> LargeBlockCache {
        LargeBlockCache {
            slot: Mutex::new(Slot {
                kept: None,
                last_freed: None,
            }),
        }
    }

    fn keeps(layout: Layout) -> bool {
        (KEEP_FROM..=KEEP_UP_TO).contains(&layout.size())
    }

    /// The slot (the lock never allocates, and a poisoned lock still holds a valid slot:
    /// nothing panics while holding it).
    fn slot(&self) -> std::sync::MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The kept block, taken.
    fn take(&self) -> Option<Kept> {
        self.slot().kept.take()
    }

    /// A large block freed: kept if the large block freed before it had its layout (a size that
    /// recurs, as a frame-sized output made per call), giving back the block kept before; else
    /// returned (with the one kept, whose size no longer recurs).
    fn freed(&self, freed: Kept) -> [Option<Kept>; 2] {
        let mut slot = self.slot();
        let recurs = slot.last_freed.replace(freed.layout) == Some(freed.layout);
        if recurs {
            [slot.kept.replace(freed), None]
        } else {
            [slot.kept.take(), Some(freed)]
        }
    }
}

impl Default for LargeBlockCache {
    fn default() -> LargeBlockCache {
        LargeBlockCache::new()
    }
}

// SAFETY: every block handed out comes from `System` with the layout it is handed out for (a
// kept block is reused only for an identical layout), and every block goes back to `System` with
// the layout it was allocated with, so `System`'s contract holds for each of them.
unsafe impl GlobalAlloc for LargeBlockCache {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if Self::keeps(layout) {
            if let Some(kept) = self.take() {
                if kept.layout == layout {
                    return kept.ptr as *mut u8;
                }
                // SAFETY: allocated by `System` with `kept.layout`, and no longer in use.
                unsafe { System.dealloc(kept.ptr as *mut u8, kept.layout) };
            }
        }
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc` requires of it.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if Self::keeps(layout) {
            let freed = Kept {
                ptr: ptr as usize,
                layout,
            };
            for back in self.freed(freed).into_iter().flatten() {
                // SAFETY: allocated by `System` with `back.layout`, and no longer in use.
                unsafe { System.dealloc(back.ptr as *mut u8, back.layout) };
            }
            return;
        }
        // SAFETY: `ptr` came from `System` (directly, or kept with this very layout).
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // Fresh pages are zero already; a kept block would have to be cleared.
        // SAFETY: the caller's layout, as `GlobalAlloc::alloc_zeroed` requires of it.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // Every block is `System`'s with its layout, so `System` may grow it in place (mremap).
        // SAFETY: the caller's block, layout and size, as `GlobalAlloc::realloc` requires.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_block_of_a_recurring_size_serves_the_next_allocation_of_its_layout_only() {
        let cache = LargeBlockCache::new();
        let big = Layout::from_size_align(KEEP_FROM, 64).unwrap();
        let other = Layout::from_size_align(KEEP_FROM + 4096, 64).unwrap();
        let small = Layout::from_size_align(4096, 8).unwrap();
        // SAFETY: each block is written within its layout and freed once with it.
        unsafe {
            // The first of its size freed is returned; the second is kept.
            let a = cache.alloc(big);
            assert!(!a.is_null());
            cache.dealloc(a, big);
            assert!(cache.slot().kept.is_none(), "a size seen once");
            let b = cache.alloc(big);
            b.write_bytes(7, big.size());
            cache.dealloc(b, big);
            let c = cache.alloc(big);
            assert_eq!(c, b, "the kept block, with what it held");
            assert_eq!(*c.add(big.size() - 1), 7);
            // Another size allocated: the kept block is returned first.
            cache.dealloc(c, big);
            let d = cache.alloc(other);
            assert!(cache.slot().kept.is_none(), "nothing kept beside it");
            // Another size freed: returned, and so is a block kept before.
            let e = cache.alloc(big);
            cache.dealloc(e, big);
            assert!(cache.slot().kept.is_some());
            cache.dealloc(d, other);
            assert!(cache.slot().kept.is_none(), "the size changed");
            // Small and huge blocks are never kept, nor change the recurring size.
            let f = cache.alloc(other);
            cache.dealloc(f, other);
            let g = cache.alloc(small);
            cache.dealloc(g, small);
            let huge = Layout::from_size_align(KEEP_UP_TO + 1, 64).unwrap();
            let h = cache.alloc(huge);
            cache.dealloc(h, huge);
            assert_eq!(cache.slot().kept.as_ref().map(|k| k.layout), Some(other));
            // Grown in place or moved, a block stays the system's; zeroed ones are fresh.
            let i = cache.alloc(small);
            i.write_bytes(3, 16);
            let j = cache.realloc(i, small, 2 * big.size());
            assert_eq!(*j.add(15), 3);
            let z = cache.alloc_zeroed(other);
            assert_eq!(*z.add(other.size() / 2), 0);
            assert!(cache.slot().kept.is_some(), "not taken for a zeroed block");
            cache.dealloc(z, other);
            cache.dealloc(j, Layout::from_size_align(2 * big.size(), 8).unwrap());
            if let Some(kept) = cache.take() {
                System.dealloc(kept.ptr as *mut u8, kept.layout);
            }
        }
    }
}
