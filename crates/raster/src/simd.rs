//! Vectors of f64 lanes for the per-pixel loops ([`F64s`]: 2 lanes with SSE2 on any x86-64 or plain f64 elsewhere,
//! 4 with AVX2, 8 with AVX-512) and the instruction set picked at run time ([`Isa`]), so that one portable build
//! still uses 256- and 512-bit vectors. A loop written once over [`F64s`] with the same operations in the same
//! order (and no fused multiply-adds) gives the same bits per lane on every instruction set.

/// Instruction set of the vectorised loops (the forward rasterizer's rows, the vertex-gradient sweeps). Every
/// choice gives the same bits; only the speed differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// The target's baseline (SSE2 on x86-64, NEON on arm64).
    Portable,
    /// AVX2 (x86-64 only; [`Isa::detect`] picks it when the CPU has it).
    Avx2,
    /// AVX-512 (F, DQ and VL, with AVX2; x86-64 only): 8 lanes; the OUT sweeps take two blocks of 4 pixels per
    /// vector and add them to the block accumulators one after the other, so the same bits as AVX2.
    Avx512,
}

impl Isa {
    /// The fastest instruction set this CPU supports.
    pub fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && has!("avx512f") && has!("avx512dq") && has!("avx512vl") {
                return Isa::Avx512;
            }
            if has!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }

    /// Whether this CPU can run `self` (each instruction set includes the ones before it).
    pub fn available(self) -> bool {
        self <= Isa::detect()
    }

    /// `Ok` where this CPU can run `self`, else an error naming the argument `isa`.
    pub fn check(self) -> crate::error::Result<()> {
        match self.available() {
            true => Ok(()),
            false => Err(crate::error::RasterError::Parameter {
                arg: "isa",
                message: format!("{self:?} is not supported by this CPU"),
            }),
        }
    }

    /// Every instruction set this CPU can run, from the baseline up.
    pub fn all_available() -> Vec<Isa> {
        [Isa::Portable, Isa::Avx2, Isa::Avx512]
            .into_iter()
            .filter(|isa| isa.available())
            .collect()
    }
}

/// Lanes of the widest vector (AVX-512's 8): the padding a buffer needs for a vector read at its last value.
pub(crate) const MAX_LANES: usize = 8;

/// `0, 1, ..., MAX_LANES - 1`, for [`F64s::counting_from`].
const LANE_OFFSETS: [f64; MAX_LANES] = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];

/// A vector of f64 lanes with the operations of the rasterizer's and the sweeps' loops. Comparisons give lanes of
/// all ones (true) or all zeros (false), which `and` applies as masks.
///
/// # Safety
/// An implementation may use instructions beyond the target's baseline: its methods may only be called on CPUs
/// that have them.
#[allow(unsafe_code)]
pub(crate) unsafe trait F64s: Copy {
    /// Lanes.
    const N: usize;
    /// Loads `N` values from `p`.
    ///
    /// # Safety
    /// `p` must be valid for `N` reads.
    unsafe fn load(p: *const f64) -> Self;
    /// Loads `N` f32 values from `p`, converted to f64 (exactly).
    ///
    /// # Safety
    /// `p` must be valid for `N` reads.
    unsafe fn load_f32(p: *const f32) -> Self;
    /// Loads `N` i32 values from `p`, converted to f64 (exactly).
    ///
    /// # Safety
    /// `p` must be valid for `N` reads.
    unsafe fn load_i32(p: *const i32) -> Self;
    /// Stores the lanes to `p`.
    ///
    /// # Safety
    /// `p` must be valid for `N` writes.
    unsafe fn store(self, p: *mut f64);
    /// All lanes `x`.
    unsafe fn splat(x: f64) -> Self;
    /// Lane-wise `+`.
    unsafe fn add(self, o: Self) -> Self;
    /// Lane-wise `-`.
    unsafe fn sub(self, o: Self) -> Self;
    /// Lane-wise `*`.
    unsafe fn mul(self, o: Self) -> Self;
    /// Lane-wise `/`.
    unsafe fn div(self, o: Self) -> Self;
    /// Lane-wise `>` (false on NaN).
    unsafe fn gt(self, o: Self) -> Self;
    /// Lane-wise `<` (false on NaN).
    unsafe fn lt(self, o: Self) -> Self;
    /// Lane-wise `==` (false on NaN).
    unsafe fn eq(self, o: Self) -> Self;
    /// Lane-wise `!=` (true on NaN).
    unsafe fn ne(self, o: Self) -> Self;
    /// Bitwise and.
    unsafe fn and(self, o: Self) -> Self;
    /// Bitwise or.
    unsafe fn or(self, o: Self) -> Self;
    /// Bitwise `!self & o`.
    unsafe fn andnot(self, o: Self) -> Self;
    /// Lane-wise `if self < o { self } else { o }` (x86's `min`: `o` when either is NaN or both are zeros).
    unsafe fn min(self, o: Self) -> Self;
    /// Lanes `x, x + 1, ..., x + N - 1` (pixel positions: sums of small integers, exact).
    #[inline(always)]
    unsafe fn counting_from(x: f64) -> Self {
        Self::splat(x).add(Self::load(LANE_OFFSETS.as_ptr()))
    }
    /// The depth test with ties: lane-wise `self > o`, or `self >= o` where `wins_ties` (a mask) is set.
    #[inline(always)]
    unsafe fn nearer(self, o: Self, wins_ties: Self) -> Self {
        self.gt(o).or(self.eq(o).and(wins_ties))
    }
}

/// Two plain f64 lanes (targets without an intrinsic implementation; the compiler vectorises what it can).
#[allow(unsafe_code)]
// SAFETY: plain Rust, no special instructions.
unsafe impl F64s for [f64; 2] {
    const N: usize = 2;
    #[inline(always)]
    unsafe fn load(p: *const f64) -> Self {
        [*p, *p.add(1)]
    }
    #[inline(always)]
    unsafe fn load_f32(p: *const f32) -> Self {
        [*p as f64, *p.add(1) as f64]
    }
    #[inline(always)]
    unsafe fn load_i32(p: *const i32) -> Self {
        [*p as f64, *p.add(1) as f64]
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f64) {
        *p = self[0];
        *p.add(1) = self[1];
    }
    #[inline(always)]
    unsafe fn splat(x: f64) -> Self {
        [x, x]
    }
    #[inline(always)]
    unsafe fn add(self, o: Self) -> Self {
        [self[0] + o[0], self[1] + o[1]]
    }
    #[inline(always)]
    unsafe fn sub(self, o: Self) -> Self {
        [self[0] - o[0], self[1] - o[1]]
    }
    #[inline(always)]
    unsafe fn mul(self, o: Self) -> Self {
        [self[0] * o[0], self[1] * o[1]]
    }
    #[inline(always)]
    unsafe fn div(self, o: Self) -> Self {
        [self[0] / o[0], self[1] / o[1]]
    }
    #[inline(always)]
    unsafe fn gt(self, o: Self) -> Self {
        bits2(self[0] > o[0], self[1] > o[1])
    }
    #[inline(always)]
    unsafe fn lt(self, o: Self) -> Self {
        bits2(self[0] < o[0], self[1] < o[1])
    }
    #[inline(always)]
    unsafe fn eq(self, o: Self) -> Self {
        bits2(self[0] == o[0], self[1] == o[1])
    }
    #[inline(always)]
    unsafe fn ne(self, o: Self) -> Self {
        bits2(self[0] != o[0], self[1] != o[1])
    }
    #[inline(always)]
    unsafe fn and(self, o: Self) -> Self {
        let f = |a: f64, b: f64| f64::from_bits(a.to_bits() & b.to_bits());
        [f(self[0], o[0]), f(self[1], o[1])]
    }
    #[inline(always)]
    unsafe fn or(self, o: Self) -> Self {
        let f = |a: f64, b: f64| f64::from_bits(a.to_bits() | b.to_bits());
        [f(self[0], o[0]), f(self[1], o[1])]
    }
    #[inline(always)]
    unsafe fn andnot(self, o: Self) -> Self {
        let f = |a: f64, b: f64| f64::from_bits(!a.to_bits() & b.to_bits());
        [f(self[0], o[0]), f(self[1], o[1])]
    }
    #[inline(always)]
    unsafe fn min(self, o: Self) -> Self {
        let f = |a: f64, b: f64| if a < b { a } else { b };
        [f(self[0], o[0]), f(self[1], o[1])]
    }
}

/// Mask lanes from two booleans.
#[inline(always)]
fn bits2(a: bool, b: bool) -> [f64; 2] {
    let m = |x: bool| f64::from_bits(if x { u64::MAX } else { 0 });
    [m(a), m(b)]
}

/// SSE2 (every x86-64 CPU), AVX2 and AVX-512 vectors.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    use super::F64s;

    // SAFETY: SSE2 is part of the x86-64 baseline.
    unsafe impl F64s for __m128d {
        const N: usize = 2;
        #[inline(always)]
        unsafe fn load(p: *const f64) -> Self {
            _mm_loadu_pd(p)
        }
        #[inline(always)]
        unsafe fn load_f32(p: *const f32) -> Self {
            _mm_cvtps_pd(_mm_castsi128_ps(_mm_loadl_epi64(p.cast())))
        }
        #[inline(always)]
        unsafe fn load_i32(p: *const i32) -> Self {
            _mm_cvtepi32_pd(_mm_loadl_epi64(p.cast()))
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f64) {
            _mm_storeu_pd(p, self)
        }
        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            _mm_set1_pd(x)
        }
        #[inline(always)]
        unsafe fn add(self, o: Self) -> Self {
            _mm_add_pd(self, o)
        }
        #[inline(always)]
        unsafe fn sub(self, o: Self) -> Self {
            _mm_sub_pd(self, o)
        }
        #[inline(always)]
        unsafe fn mul(self, o: Self) -> Self {
            _mm_mul_pd(self, o)
        }
        #[inline(always)]
        unsafe fn div(self, o: Self) -> Self {
            _mm_div_pd(self, o)
        }
        #[inline(always)]
        unsafe fn gt(self, o: Self) -> Self {
            _mm_cmpgt_pd(self, o)
        }
        #[inline(always)]
        unsafe fn lt(self, o: Self) -> Self {
            _mm_cmplt_pd(self, o)
        }
        #[inline(always)]
        unsafe fn eq(self, o: Self) -> Self {
            _mm_cmpeq_pd(self, o)
        }
        #[inline(always)]
        unsafe fn ne(self, o: Self) -> Self {
            _mm_cmpneq_pd(self, o)
        }
        #[inline(always)]
        unsafe fn and(self, o: Self) -> Self {
            _mm_and_pd(self, o)
        }
        #[inline(always)]
        unsafe fn or(self, o: Self) -> Self {
            _mm_or_pd(self, o)
        }
        #[inline(always)]
        unsafe fn andnot(self, o: Self) -> Self {
            _mm_andnot_pd(self, o)
        }
        #[inline(always)]
        unsafe fn min(self, o: Self) -> Self {
            _mm_min_pd(self, o)
        }
    }

    // SAFETY: callers check AVX2 at run time (`Isa::Avx2`).
    unsafe impl F64s for __m256d {
        const N: usize = 4;
        #[inline(always)]
        unsafe fn load(p: *const f64) -> Self {
            _mm256_loadu_pd(p)
        }
        #[inline(always)]
        unsafe fn load_f32(p: *const f32) -> Self {
            _mm256_cvtps_pd(_mm_loadu_ps(p))
        }
        #[inline(always)]
        unsafe fn load_i32(p: *const i32) -> Self {
            _mm256_cvtepi32_pd(_mm_loadu_si128(p.cast()))
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f64) {
            _mm256_storeu_pd(p, self)
        }
        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            _mm256_set1_pd(x)
        }
        #[inline(always)]
        unsafe fn add(self, o: Self) -> Self {
            _mm256_add_pd(self, o)
        }
        #[inline(always)]
        unsafe fn sub(self, o: Self) -> Self {
            _mm256_sub_pd(self, o)
        }
        #[inline(always)]
        unsafe fn mul(self, o: Self) -> Self {
            _mm256_mul_pd(self, o)
        }
        #[inline(always)]
        unsafe fn div(self, o: Self) -> Self {
            _mm256_div_pd(self, o)
        }
        #[inline(always)]
        unsafe fn gt(self, o: Self) -> Self {
            _mm256_cmp_pd::<_CMP_GT_OQ>(self, o)
        }
        #[inline(always)]
        unsafe fn lt(self, o: Self) -> Self {
            _mm256_cmp_pd::<_CMP_LT_OQ>(self, o)
        }
        #[inline(always)]
        unsafe fn eq(self, o: Self) -> Self {
            _mm256_cmp_pd::<_CMP_EQ_OQ>(self, o)
        }
        #[inline(always)]
        unsafe fn ne(self, o: Self) -> Self {
            _mm256_cmp_pd::<_CMP_NEQ_UQ>(self, o)
        }
        #[inline(always)]
        unsafe fn and(self, o: Self) -> Self {
            _mm256_and_pd(self, o)
        }
        #[inline(always)]
        unsafe fn or(self, o: Self) -> Self {
            _mm256_or_pd(self, o)
        }
        #[inline(always)]
        unsafe fn andnot(self, o: Self) -> Self {
            _mm256_andnot_pd(self, o)
        }
        #[inline(always)]
        unsafe fn min(self, o: Self) -> Self {
            _mm256_min_pd(self, o)
        }
        #[inline(always)]
        unsafe fn nearer(self, o: Self, wins_ties: Self) -> Self {
            // One instruction fewer than the default (same lanes: the masks are all ones or all zeros).
            let (gt, ge) = (
                _mm256_cmp_pd::<_CMP_GT_OQ>(self, o),
                _mm256_cmp_pd::<_CMP_GE_OQ>(self, o),
            );
            _mm256_blendv_pd(gt, ge, wins_ties)
        }
    }

    // SAFETY: callers check AVX-512F, -DQ and -VL at run time (`Isa::Avx512`). Comparisons give AVX-512 masks,
    // widened to lanes of all ones or zeros (the compiler folds them back into masked operations).
    unsafe impl F64s for __m512d {
        const N: usize = 8;
        #[inline(always)]
        unsafe fn load(p: *const f64) -> Self {
            _mm512_loadu_pd(p)
        }
        #[inline(always)]
        unsafe fn load_f32(p: *const f32) -> Self {
            _mm512_cvtps_pd(_mm256_loadu_ps(p))
        }
        #[inline(always)]
        unsafe fn load_i32(p: *const i32) -> Self {
            _mm512_cvtepi32_pd(_mm256_loadu_si256(p.cast()))
        }
        #[inline(always)]
        unsafe fn store(self, p: *mut f64) {
            _mm512_storeu_pd(p, self)
        }
        #[inline(always)]
        unsafe fn splat(x: f64) -> Self {
            _mm512_set1_pd(x)
        }
        #[inline(always)]
        unsafe fn add(self, o: Self) -> Self {
            _mm512_add_pd(self, o)
        }
        #[inline(always)]
        unsafe fn sub(self, o: Self) -> Self {
            _mm512_sub_pd(self, o)
        }
        #[inline(always)]
        unsafe fn mul(self, o: Self) -> Self {
            _mm512_mul_pd(self, o)
        }
        #[inline(always)]
        unsafe fn div(self, o: Self) -> Self {
            _mm512_div_pd(self, o)
        }
        #[inline(always)]
        unsafe fn gt(self, o: Self) -> Self {
            lanes_of(_mm512_cmp_pd_mask::<_CMP_GT_OQ>(self, o))
        }
        #[inline(always)]
        unsafe fn lt(self, o: Self) -> Self {
            lanes_of(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(self, o))
        }
        #[inline(always)]
        unsafe fn eq(self, o: Self) -> Self {
            lanes_of(_mm512_cmp_pd_mask::<_CMP_EQ_OQ>(self, o))
        }
        #[inline(always)]
        unsafe fn ne(self, o: Self) -> Self {
            lanes_of(_mm512_cmp_pd_mask::<_CMP_NEQ_UQ>(self, o))
        }
        #[inline(always)]
        unsafe fn and(self, o: Self) -> Self {
            _mm512_and_pd(self, o)
        }
        #[inline(always)]
        unsafe fn or(self, o: Self) -> Self {
            _mm512_or_pd(self, o)
        }
        #[inline(always)]
        unsafe fn andnot(self, o: Self) -> Self {
            _mm512_andnot_pd(self, o)
        }
        #[inline(always)]
        unsafe fn min(self, o: Self) -> Self {
            _mm512_min_pd(self, o)
        }
    }

    /// An AVX-512 mask as lanes of all ones (set) or all zeros.
    #[inline(always)]
    unsafe fn lanes_of(m: __mmask8) -> __m512d {
        _mm512_castsi512_pd(_mm512_movm_epi64(m))
    }
}
