//! Running work on a rayon pool with a chosen thread count.

use std::cell::RefCell;
use std::sync::Arc;

use crate::error::{RasterError, Result};

/// Largest accepted explicit thread count.
pub const MAX_THREADS: usize = 1024;

/// How many explicitly sized pools each calling thread keeps alive between its calls (most recently used first).
/// A pool evicted from the cache is dropped once the calls still running on it finish, and its threads exit, so
/// calling with many distinct thread counts does not accumulate threads.
pub const MAX_CACHED_POOLS: usize = 2;

thread_local! {
    /// The calling thread's explicitly sized pools, most recently used first (dropped with the thread).
    static POOLS: RefCell<Vec<(usize, Arc<rayon::ThreadPool>)>> = const { RefCell::new(Vec::new()) };
}

/// The calling thread's pool of `num_threads` threads, from its bounded most-recently-used cache or newly built
/// (not cached while the thread is being torn down).
fn pool_for(num_threads: usize) -> Result<Arc<rayon::ThreadPool>> {
    let build = || {
        rayon::ThreadPoolBuilder::new()
            .num_threads(num_threads)
            .build()
            .map(Arc::new)
            .map_err(|e| RasterError::ThreadPool {
                threads: num_threads,
                message: e.to_string(),
            })
    };
    POOLS
        .try_with(|cache| {
            let mut cache = cache.borrow_mut();
            if let Some(pos) = cache.iter().position(|(n, _)| *n == num_threads) {
                let entry = cache.remove(pos);
                let pool = entry.1.clone();
                cache.insert(0, entry);
                return Ok(pool);
            }
            let pool = build()?;
            cache.insert(0, (num_threads, pool.clone()));
            cache.truncate(MAX_CACHED_POOLS);
            Ok(pool)
        })
        .unwrap_or_else(|_| build())
}

/// Runs `op` with `num_threads` rayon threads (0 = the global pool). An explicit count runs on a pool of the calling
/// thread's own (at most [`MAX_CACHED_POOLS`] kept per thread for reuse), so threads calling at the same time (an
/// attack's step workers) neither queue behind each other's work nor share one pool's threads. Results of this
/// crate do not depend on the thread count.
pub fn with_threads<R: Send>(num_threads: usize, op: impl FnOnce() -> R + Send) -> Result<R> {
    if num_threads == 0 {
        return Ok(op());
    }
    if num_threads > MAX_THREADS {
        return Err(RasterError::Parameter {
            arg: "num_threads",
            message: format!("must be in [0, {MAX_THREADS}], got {num_threads}"),
        });
    }
    let pool = pool_for(num_threads)?;
    Ok(pool.install(op))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pool_cache_stays_bounded() {
        for n in 1..=8 {
            let got = with_threads(n, rayon::current_num_threads).expect("pool");
            assert_eq!(got, n);
        }
        let cached = POOLS.with_borrow(|cache| cache.iter().map(|(n, _)| *n).collect::<Vec<_>>());
        let latest: Vec<usize> = (1..=8).rev().take(MAX_CACHED_POOLS).collect();
        assert_eq!(
            cached, latest,
            "the calling thread keeps its most recent pools"
        );
    }

    #[test]
    fn threads_calling_at_once_get_pools_of_their_own() {
        // Two callers asking for one thread each: with one shared pool both calls would run on its one thread.
        let barrier = std::sync::Barrier::new(2);
        let ran_on = std::thread::scope(|s| {
            let callers: Vec<_> = (0..2)
                .map(|_| {
                    s.spawn(|| {
                        barrier.wait();
                        let on = with_threads(1, || std::thread::current().id()).expect("pool");
                        (std::thread::current().id(), on)
                    })
                })
                .collect();
            callers
                .into_iter()
                .map(|c| c.join().expect("caller"))
                .collect::<Vec<_>>()
        });
        let (a, b) = (ran_on[0], ran_on[1]);
        assert_ne!(a.1, b.1, "both callers ran on one pool thread");
        assert!(
            a.1 != a.0 && b.1 != b.0,
            "an explicit pool runs on its own threads"
        );
    }

    #[test]
    fn too_many_threads_is_a_parameter_error() {
        assert!(matches!(
            with_threads(MAX_THREADS + 1, || ()),
            Err(RasterError::Parameter {
                arg: "num_threads",
                ..
            })
        ));
    }
}
