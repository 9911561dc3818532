//! CPU feature detection for the SIMD kernels of dynapix, in one place.
//!
//! Each instruction set a kernel needs has a zero-sized token ([`Avx2`], [`Avx512F`],
//! [`Avx512Vl`]). A token can only be obtained from its `detect()`, which returns `Some` when
//! the running CPU (and the operating system) supports the instruction set, so holding one is
//! a proof. The idiom for a kernel, used in every crate of the workspace:
//!
//! ```
//! use dynapix_simd::Avx2;
//!
//! /// The portable version: the reference the kernel is tested against.
//! fn sum_body(x: &[f32]) -> f32 {
//!     x.iter().sum()
//! }
//!
//! /// The kernel: the same code compiled for AVX2. The token parameter keeps it from being
//! /// called without a proof, even in `unsafe` code.
//! #[cfg(target_arch = "x86_64")]
//! #[target_feature(enable = "avx2")]
//! fn sum_avx2(_: Avx2, x: &[f32]) -> f32 {
//!     sum_body(x)
//! }
//!
//! fn sum(x: &[f32]) -> f32 {
//!     #[cfg(target_arch = "x86_64")]
//!     if let Some(avx2) = Avx2::detect() {
//!         // SAFETY: the token proves the CPU has AVX2.
//!         return unsafe { sum_avx2(avx2, x) };
//!     }
//!     sum_body(x)
//! }
//! assert_eq!(sum(&[1.0, 2.0, 3.0]), 6.0);
//! ```
//!
//! A closure can be compiled for AVX2 with [`Avx2::vectorize`] (for row closures handed to
//! rayon, which do not inherit the target features of the function that defines them).
//!
//! Detection runs once per token type and is cached. On other architectures than x86-64 no
//! token is ever returned, and the kernels are not compiled.

#![deny(missing_docs)]

use std::sync::atomic::{AtomicU8, Ordering};

/// A cached answer of a detection: 0 = not asked yet, 1 = absent, 2 = present.
struct Cache(AtomicU8);

impl Cache {
    const fn new() -> Self {
        Self(AtomicU8::new(0))
    }

    /// The cached answer, computing it with `detect` the first time.
    #[inline]
    fn get(&self, detect: fn() -> bool) -> bool {
        match self.0.load(Ordering::Relaxed) {
            0 => {
                let present = detect();
                self.0.store(if present { 2 } else { 1 }, Ordering::Relaxed);
                present
            }
            v => v == 2,
        }
    }
}

/// Proof that the CPU has AVX2 (and so AVX and everything before it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Avx2(());

impl Avx2 {
    /// `Some` when the CPU has AVX2 (detected once, then cached).
    #[inline]
    pub fn detect() -> Option<Self> {
        static CACHE: Cache = Cache::new();
        CACHE.get(detect_avx2).then_some(Self(()))
    }

    /// Runs `f` inside a function compiled for AVX2, so that the closure's body, inlined
    /// there, is built for AVX2 (eight `f32` lanes) rather than for the baseline (SSE2).
    ///
    /// A closure is compiled on its own, without the target features of the function that
    /// defines it; this is how a row closure handed to rayon gets them. Element-wise
    /// arithmetic without fused multiply-add (Rust never contracts `a * b + c`) rounds the
    /// same in either build.
    #[inline(always)]
    pub fn vectorize<R>(self, f: impl FnOnce() -> R) -> R {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn avx2<R>(_: Avx2, f: impl FnOnce() -> R) -> R {
                f()
            }
            // SAFETY: the token proves the CPU has AVX2.
            unsafe { avx2(self, f) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = self;
            f()
        }
    }
}

/// Proof that the CPU has AVX-512F (the foundation, `zmm` registers) and AVX2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Avx512F(());

impl Avx512F {
    /// `Some` when the CPU has AVX-512F and AVX2 (detected once, then cached).
    #[inline]
    pub fn detect() -> Option<Self> {
        static CACHE: Cache = Cache::new();
        CACHE.get(detect_avx512f).then_some(Self(()))
    }

    /// The AVX2 this CPU also has.
    #[inline]
    pub fn avx2(self) -> Avx2 {
        Avx2(())
    }
}

/// Proof that the CPU has AVX-512F with the vector-length extension AVX-512VL (the AVX-512
/// instructions and 32 registers for 128- and 256-bit vectors), and AVX2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Avx512Vl(());

impl Avx512Vl {
    /// `Some` when the CPU has AVX-512F, AVX-512VL and AVX2 (detected once, then cached).
    #[inline]
    pub fn detect() -> Option<Self> {
        static CACHE: Cache = Cache::new();
        CACHE.get(detect_avx512vl).then_some(Self(()))
    }

    /// The AVX-512F this CPU also has.
    #[inline]
    pub fn avx512f(self) -> Avx512F {
        Avx512F(())
    }

    /// The AVX2 this CPU also has.
    #[inline]
    pub fn avx2(self) -> Avx2 {
        Avx2(())
    }
}

#[cfg(target_arch = "x86_64")]
fn detect_avx2() -> bool {
    std::is_x86_feature_detected!("avx2")
}

#[cfg(target_arch = "x86_64")]
fn detect_avx512f() -> bool {
    detect_avx2() && std::is_x86_feature_detected!("avx512f")
}

#[cfg(target_arch = "x86_64")]
fn detect_avx512vl() -> bool {
    detect_avx512f() && std::is_x86_feature_detected!("avx512vl")
}

#[cfg(not(target_arch = "x86_64"))]
fn detect_avx2() -> bool {
    false
}

#[cfg(not(target_arch = "x86_64"))]
fn detect_avx512f() -> bool {
    false
}

#[cfg(not(target_arch = "x86_64"))]
fn detect_avx512vl() -> bool {
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_agree_with_the_standard_library_and_imply_each_other() {
        #[cfg(target_arch = "x86_64")]
        {
            assert_eq!(
                Avx2::detect().is_some(),
                std::is_x86_feature_detected!("avx2")
            );
            assert_eq!(
                Avx512F::detect().is_some(),
                std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("avx512f")
            );
        }
        // Asking twice gives the cached answer, and a stronger token implies the weaker ones.
        assert_eq!(Avx2::detect(), Avx2::detect());
        if let Some(vl) = Avx512Vl::detect() {
            assert_eq!(Some(vl.avx512f()), Avx512F::detect());
            assert_eq!(Some(vl.avx2()), Avx2::detect());
        }
        if let Some(f) = Avx512F::detect() {
            assert_eq!(Some(f.avx2()), Avx2::detect());
        }
    }

    #[test]
    fn a_vectorized_closure_computes_the_same_bits() {
        let x: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin() * 1e3).collect();
        let portable: Vec<f32> = x.iter().map(|v| v * 1.5 + 0.25).collect();
        let Some(avx2) = Avx2::detect() else {
            eprintln!("skipping: no AVX2 on this CPU");
            return;
        };
        let vector = avx2.vectorize(|| x.iter().map(|v| v * 1.5 + 0.25).collect::<Vec<f32>>());
        assert_eq!(vector, portable);
        assert_eq!(avx2.vectorize(|| 7), 7);
    }
}
