//! The per-batch-element buffers of the backward pass, kept between calls.
//!
//! Allocating them anew on every call (about 10 MB for a 299 x 299 image) would cost a page fault per 4 KiB page:
//! glibc returns a thread arena's freed top to the kernel (`madvise(MADV_DONTNEED)`) when a call ends, so the next
//! call would fault every page in again. A call takes a [`Workspace`] from a process-wide pool, refills its buffers in
//! place (every value is rewritten before it is read; nothing relies on fresh zeros) and gives it back. One
//! workspace is in use per batch element being computed, so the pool holds about as many as elements ran at once.
//! At most [`MAX_KEPT_BYTES`] are kept in all; a workspace that would go beyond is freed.

use std::sync::Mutex;

use crate::setup::FaceSetup;

use super::lines::Lines;
use super::Drawn;

/// The most memory (bytes, all workspaces together) the pool keeps between calls.
pub const MAX_KEPT_BYTES: usize = 256 << 20;

/// Buffers of one batch element's backward; each is refilled from empty by the code that uses it.
#[derive(Default)]
pub(super) struct Workspace {
    /// Row lines.
    pub rows: Lines,
    /// Column lines.
    pub cols: Lines,
    /// Per-face setups (drawn faces only; the others default).
    pub setups: Vec<FaceSetup>,
    /// Per-face drawn boxes.
    pub drawn: Vec<Drawn>,
    /// `(M, C)` attribute gradient accumulator.
    pub acc: Vec<f64>,
    /// `(M + 1, C)` colours as f64: the face attributes, then the background.
    pub colors: Vec<f64>,
    /// Per-face vertex-gradient partials.
    pub partials: Vec<[[f64; 2]; 3]>,
    /// `(N, 2)` vertex gradient accumulator.
    pub accv: Vec<f64>,
}

impl Workspace {
    /// Bytes held (capacity) by the buffers.
    pub fn bytes(&self) -> usize {
        fn held<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        self.rows.bytes()
            + self.cols.bytes()
            + held(&self.setups)
            + held(&self.drawn)
            + held(&self.acc)
            + held(&self.colors)
            + held(&self.partials)
            + held(&self.accv)
    }
}

/// The kept workspaces.
static POOL: Mutex<Vec<Workspace>> = Mutex::new(Vec::new());

/// A kept workspace, or an empty one when none is left.
pub(super) fn take() -> Workspace {
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    pool.pop().unwrap_or_default()
}

/// Keeps `ws` for a later call, or frees it when the pool would then hold more than [`MAX_KEPT_BYTES`].
pub(super) fn give(ws: Workspace) {
    let bytes = ws.bytes();
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    let kept: usize = pool.iter().map(Workspace::bytes).sum();
    if kept.saturating_add(bytes) <= MAX_KEPT_BYTES {
        pool.push(ws);
        return;
    }
    drop(pool);
    drop(ws);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pool_frees_what_would_exceed_its_cap() {
        let mut big = Workspace::default();
        // Reserved, never touched: address space only.
        big.acc.reserve_exact(MAX_KEPT_BYTES / 8 + 1);
        let ptr = big.acc.as_ptr();
        give(big);
        let pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        assert!(pool.iter().all(|ws| ws.acc.as_ptr() != ptr));
        assert!(pool.iter().map(Workspace::bytes).sum::<usize>() <= MAX_KEPT_BYTES);
    }

    #[test]
    fn a_workspace_given_back_is_kept() {
        let mut ws = Workspace::default();
        ws.accv.reserve_exact(1000);
        let ptr = ws.accv.as_ptr();
        give(ws);
        // Other tests may give and take at the same time, so look for it among the kept ones.
        let pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        assert!(pool.iter().any(|ws| ws.accv.as_ptr() == ptr));
    }
}
