//! Running work on a rayon pool with a chosen thread count.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use crate::error::{RasterError, Result};

/// Largest accepted explicit thread count.
pub const MAX_THREADS: usize = 1024;

fn pools() -> &'static Mutex<HashMap<usize, Arc<rayon::ThreadPool>>> {
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<rayon::ThreadPool>>>> = OnceLock::new();
    POOLS.get_or_init(|| Mutex::new(HashMap::new()))
}

/// Runs `op` with `num_threads` rayon threads (0 = the global pool). Pools are created once per thread count and
/// reused. Results of this crate do not depend on the thread count.
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
    let pool = {
        let mut map = pools().lock().unwrap_or_else(|e| e.into_inner());
        match map.get(&num_threads) {
            Some(p) => p.clone(),
            None => {
                let p = rayon::ThreadPoolBuilder::new()
                    .num_threads(num_threads)
                    .build()
                    .map_err(|e| RasterError::ThreadPool {
                        threads: num_threads,
                        message: e.to_string(),
                    })?;
                let p = Arc::new(p);
                map.insert(num_threads, p.clone());
                p
            }
        }
    };
    Ok(pool.install(op))
}
