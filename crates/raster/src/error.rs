//! Typed errors of the raster core. Every variant names the argument at fault and what was expected.

use thiserror::Error;

/// The kind of Python exception a [`RasterError`] should become in the bindings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// A bad value or shape (`ValueError`).
    Value,
    /// An index out of range (`IndexError`).
    Index,
    /// An output buffer could not be allocated (`MemoryError`).
    Memory,
}

/// Errors of the raster core. Bad input never panics; it returns one of these.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RasterError {
    /// An array does not have the expected shape.
    #[error("{arg}: expected shape {expected}, got {got}")]
    Shape {
        /// Argument name.
        arg: &'static str,
        /// Expected shape, e.g. `(B, N, 3)`.
        expected: String,
        /// Actual shape or length.
        got: String,
    },
    /// A float array holds NaN or infinity.
    #[error("{arg}: non-finite value ({value}) at flat index {index}")]
    NonFinite {
        /// Argument name.
        arg: &'static str,
        /// Flat index of the first bad element.
        index: usize,
        /// The bad value.
        value: f32,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "faces: face {face} refers to vertex {vertex}, but there are only {num_vertices} vertices"
    )]
    FaceIndexOutOfRange {
        /// Face index.
        face: usize,
        /// The offending vertex index.
        vertex: i64,
        /// Number of vertices.
        num_vertices: usize,
    },
    /// A face-index map entry is neither -1 nor a valid face.
    #[error("face_index: entry {index} is {value}, expected -1 or a face in [0, {num_faces})")]
    FaceMapOutOfRange {
        /// Flat index in the map.
        index: usize,
        /// Value found.
        value: i64,
        /// Number of faces.
        num_faces: usize,
    },
    /// The mesh has no faces or no vertices.
    #[error("{arg}: the mesh is empty (need at least one face and three vertices)")]
    EmptyMesh {
        /// Argument name.
        arg: &'static str,
    },
    /// The image size is zero or absurdly large.
    #[error("{arg}: must be in [1, {max}], got {value}")]
    ImageSize {
        /// `height` or `width`.
        arg: &'static str,
        /// The value given.
        value: i64,
        /// The largest allowed value.
        max: usize,
    },
    /// The clipping range is invalid.
    #[error("near/far: need finite 0 <= near < far, got near={near}, far={far}")]
    ClipRange {
        /// Near plane.
        near: f64,
        /// Far plane.
        far: f64,
    },
    /// A scalar parameter is out of its range.
    #[error("{arg}: {message}")]
    Parameter {
        /// Argument name.
        arg: &'static str,
        /// What is expected.
        message: String,
    },
    /// Every vertex of a batch element is behind the camera.
    #[error("{arg}: every vertex of batch element {batch} is behind the camera (z <= 0)")]
    BehindCamera {
        /// Argument name.
        arg: &'static str,
        /// Batch element.
        batch: usize,
    },
    /// An output buffer could not be allocated (the image is too large for the memory left).
    #[error("{what}: cannot allocate {bytes} bytes ({gib:.2} GiB); use a smaller image size or batch", gib = *.bytes as f64 / 1073741824.0)]
    OutOfMemory {
        /// The buffer, e.g. `image`.
        what: &'static str,
        /// Bytes requested.
        bytes: usize,
    },
    /// The rayon thread pool could not be created.
    #[error("num_threads: could not create a thread pool with {threads} threads: {message}")]
    ThreadPool {
        /// Requested thread count.
        threads: usize,
        /// The underlying error.
        message: String,
    },
}

impl RasterError {
    /// Which Python exception this error maps to.
    pub fn kind(&self) -> ErrorKind {
        match self {
            RasterError::FaceIndexOutOfRange { .. } | RasterError::FaceMapOutOfRange { .. } => {
                ErrorKind::Index
            }
            RasterError::OutOfMemory { .. } => ErrorKind::Memory,
            _ => ErrorKind::Value,
        }
    }

    /// Shorthand for a [`RasterError::Shape`] error.
    pub fn shape(arg: &'static str, expected: impl Into<String>, got: impl Into<String>) -> Self {
        RasterError::Shape {
            arg,
            expected: expected.into(),
            got: got.into(),
        }
    }
}

/// A vector of `len` copies of `value`, or [`RasterError::OutOfMemory`] instead of aborting the process when
/// the allocation fails (e.g. under an address-space limit).
pub fn try_filled_vec<T: Clone>(len: usize, value: T, what: &'static str) -> Result<Vec<T>> {
    let mut v = Vec::new();
    try_refill(&mut v, len, value, what)?;
    Ok(v)
}

/// Empties `v` and makes room for `len` values in the memory it already holds (growing it only when too small),
/// or [`RasterError::OutOfMemory`] instead of aborting when growing fails. For buffers reused between calls.
pub fn try_clear_for<T>(v: &mut Vec<T>, len: usize, what: &'static str) -> Result<()> {
    v.clear();
    v.try_reserve_exact(len)
        .map_err(|_| RasterError::OutOfMemory {
            what,
            bytes: len.saturating_mul(std::mem::size_of::<T>()),
        })
}

/// `v` refilled with `len` copies of `value` (see [`try_clear_for`]).
pub fn try_refill<T: Clone>(
    v: &mut Vec<T>,
    len: usize,
    value: T,
    what: &'static str,
) -> Result<()> {
    try_clear_for(v, len, what)?;
    v.resize(len, value);
    Ok(())
}

/// A buffer being filled: `len` values to write, then `padding` copies of a value, in the buffer's memory (grown when
/// too small) without being zeroed first. Until [`Fill::done`] the buffer is empty, so its old values are never read.
pub(crate) struct Fill<'a, T> {
    buf: &'a mut Vec<T>,
    len: usize,
    padding: usize,
}

impl<'a, T: Copy> Fill<'a, T> {
    /// `buf` emptied to receive `len` values to write, followed by `padding` copies of `pad`; an error naming `what`
    /// when it cannot grow to that size.
    pub(crate) fn new(
        buf: &'a mut Vec<T>,
        len: usize,
        padding: usize,
        pad: T,
        what: &'static str,
    ) -> Result<Fill<'a, T>> {
        try_clear_for(buf, len.saturating_add(padding), what)?;
        for x in &mut buf.spare_capacity_mut()[len..len + padding] {
            x.write(pad);
        }
        Ok(Fill { buf, len, padding })
    }

    /// The `len` values to write.
    pub(crate) fn slots(&mut self) -> &mut [std::mem::MaybeUninit<T>] {
        &mut self.buf.spare_capacity_mut()[..self.len]
    }

    /// Marks the buffer filled (`len` values and the padding).
    ///
    /// # Safety
    /// Every element of [`Fill::slots`] must have been written.
    #[allow(unsafe_code)]
    pub(crate) unsafe fn done(self) {
        // SAFETY: the first `len` values are written (the caller's promise), the padding by `new`; the capacity is
        // at least `len + padding` (`new`).
        unsafe { self.buf.set_len(self.len + self.padding) };
    }
}

/// Result alias of the raster core.
pub type Result<T> = std::result::Result<T, RasterError>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_impossible_allocation_is_a_typed_error() {
        let err = try_filled_vec(usize::MAX / 2, 0f32, "image").expect_err("cannot allocate");
        assert!(matches!(
            err,
            RasterError::OutOfMemory { what: "image", .. }
        ));
        assert_eq!(err.kind(), ErrorKind::Memory);
        assert!(err.to_string().starts_with("image: cannot allocate"));
    }

    #[test]
    fn a_refilled_buffer_keeps_its_memory_and_holds_only_the_new_values() {
        let mut v = vec![7u8; 1000];
        let ptr = v.as_ptr();
        try_refill(&mut v, 600, 1u8, "v").expect("fits");
        assert_eq!((v.len(), v.as_ptr()), (600, ptr));
        assert!(v.iter().all(|&x| x == 1));
        let err = try_refill(&mut v, usize::MAX / 2, 0u8, "v").expect_err("cannot allocate");
        assert!(matches!(err, RasterError::OutOfMemory { what: "v", .. }));
    }
}
