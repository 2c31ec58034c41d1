//! Running work on a rayon pool with a chosen thread count.

use std::sync::{Arc, Mutex, OnceLock};

use crate::error::{RasterError, Result};

/// Largest accepted explicit thread count.
pub const MAX_THREADS: usize = 1024;

/// How many explicitly sized pools are kept alive between calls (most recently used first). A pool evicted
/// from the cache is dropped once the calls still running on it finish, and its threads exit, so calling
/// with many distinct thread counts does not accumulate threads.
pub const MAX_CACHED_POOLS: usize = 2;

type PoolCache = Mutex<Vec<(usize, Arc<rayon::ThreadPool>)>>;

fn pools() -> &'static PoolCache {
    static POOLS: OnceLock<PoolCache> = OnceLock::new();
    POOLS.get_or_init(|| Mutex::new(Vec::new()))
}

/// The pool for `num_threads`, from the bounded most-recently-used cache or newly built.
fn pool_for(num_threads: usize) -> Result<Arc<rayon::ThreadPool>> {
    let mut cache = pools().lock().unwrap_or_else(|e| e.into_inner());
    if let Some(pos) = cache.iter().position(|(n, _)| *n == num_threads) {
        let entry = cache.remove(pos);
        let pool = entry.1.clone();
        cache.insert(0, entry);
        return Ok(pool);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(num_threads)
        .build()
        .map_err(|e| RasterError::ThreadPool {
            threads: num_threads,
            message: e.to_string(),
        })?;
    let pool = Arc::new(pool);
    cache.insert(0, (num_threads, pool.clone()));
    cache.truncate(MAX_CACHED_POOLS);
    Ok(pool)
}

/// Runs `op` with `num_threads` rayon threads (0 = the global pool). At most [`MAX_CACHED_POOLS`] explicitly
/// sized pools are kept for reuse. Results of this crate do not depend on the thread count.
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
        let cache = pools().lock().unwrap_or_else(|e| e.into_inner());
        assert!(
            cache.len() <= MAX_CACHED_POOLS,
            "{} pools cached",
            cache.len()
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
