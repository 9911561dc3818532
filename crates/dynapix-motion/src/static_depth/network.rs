//! Sorting networks (Batcher's odd–even merge sort) that sort the views' depths of
//! [`LANES`] pixels at once, with a fixed straight-line network for the default 24 views.

/// Pixels sorted together by [`sort_lanes`].
pub(super) const LANES: usize = 8;

/// Batcher's odd–even merge sort for `n` (a power of two) inputs: the compare-exchange pairs
/// `(i, j)`, `i < j`, that leave any input sorted ascending when each pair is put in order.
fn sorting_network(n: usize) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut p = 1;
    while p < n {
        let mut k = p;
        while k >= 1 {
            let mut j = k % p;
            while j + k < n {
                for i in 0..k.min(n - j - k) {
                    if (i + j) / (2 * p) == (i + j + k) / (2 * p) {
                        pairs.push((i + j, i + j + k));
                    }
                }
                j += 2 * k;
            }
            k /= 2;
        }
        p *= 2;
    }
    pairs
}

/// A sorting network for any number `n` of rows: [`sorting_network`] of the next power of
/// two without the pairs that reach past `n`. Those rows would hold +∞, the largest value,
/// which no compare-exchange ever moves (the smaller index gets the minimum), so the pairs
/// that reach them change nothing.
pub(super) fn sorting_network_for(n: usize) -> Vec<(usize, usize)> {
    sorting_network(n.next_power_of_two())
        .into_iter()
        .filter(|&(_, j)| j < n)
        .collect()
}

/// Straight-line code for one fixed network: `$net`, its pairs as data (the test
/// `fixed_network_is_batchers` checks them against [`sorting_network_for`]), and `$name`,
/// which applies them with `ce` to `$n` rows held in local variables, so the rows live in
/// registers instead of being loaded and stored by every compare-exchange of a loop over
/// the pairs.
macro_rules! fixed_network {
    ($name:ident, $net:ident, $n:literal, [$(($i:literal, $j:literal)),* $(,)?]) => {
        /// The pairs of the fixed network (see [`fixed_network`]), for the tests.
        #[cfg(test)]
        const $net: [(usize, usize); [$($i),*].len()] = [$(($i, $j)),*];

        /// The fixed network applied to rows held by value: `ce(a, b)` returns the rows
        /// `(lo, hi)` put in order lane by lane.
        #[inline(always)]
        fn $name<T: Copy>(v: &mut [T; $n], ce: impl Fn(T, T) -> (T, T)) {
            $(
                let (lo, hi) = ce(v[$i], v[$j]);
                v[$i] = lo;
                v[$j] = hi;
            )*
        }
    };
}

/// Rows `a` and `b` in order lane by lane, by the same selection as [`sort_lanes_body`].
#[inline(always)]
fn compare_exchange(a: [f32; LANES], b: [f32; LANES]) -> ([f32; LANES], [f32; LANES]) {
    let mut lo = a;
    let mut hi = b;
    for l in 0..LANES {
        let swap = b[l] < a[l];
        lo[l] = if swap { b[l] } else { a[l] };
        hi[l] = if swap { a[l] } else { b[l] };
    }
    (lo, hi)
}

// Batcher's network for 24 rows, the default number of static-depth views: one line per
// step of the merges (a line's pairs are independent of each other).
#[rustfmt::skip]
fixed_network!(apply_network_24, NETWORK_24, 24, [
    (0, 1), (2, 3), (4, 5), (6, 7), (8, 9), (10, 11), (12, 13), (14, 15), (16, 17), (18, 19),
    (20, 21), (22, 23),
    (0, 2), (1, 3), (4, 6), (5, 7), (8, 10), (9, 11), (12, 14), (13, 15), (16, 18), (17, 19),
    (20, 22), (21, 23),
    (1, 2), (5, 6), (9, 10), (13, 14), (17, 18), (21, 22),
    (0, 4), (1, 5), (2, 6), (3, 7), (8, 12), (9, 13), (10, 14), (11, 15), (16, 20), (17, 21),
    (18, 22), (19, 23),
    (2, 4), (3, 5), (10, 12), (11, 13), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (9, 10), (11, 12), (13, 14), (17, 18), (19, 20), (21, 22),
    (0, 8), (1, 9), (2, 10), (3, 11), (4, 12), (5, 13), (6, 14), (7, 15),
    (4, 8), (5, 9), (6, 10), (7, 11),
    (2, 4), (3, 5), (6, 8), (7, 9), (10, 12), (11, 13), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (17, 18), (19, 20), (21, 22),
    (0, 16), (1, 17), (2, 18), (3, 19), (4, 20), (5, 21), (6, 22), (7, 23),
    (8, 16), (9, 17), (10, 18), (11, 19), (12, 20), (13, 21), (14, 22), (15, 23),
    (4, 8), (5, 9), (6, 10), (7, 11), (12, 16), (13, 17), (14, 18), (15, 19),
    (2, 4), (3, 5), (6, 8), (7, 9), (10, 12), (11, 13), (14, 16), (15, 17), (18, 20), (19, 21),
    (1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16), (17, 18), (19, 20),
    (21, 22),
]);

/// Sorts every lane of `cols` ascending (row `r` holds the `r`-th value of each lane) with a
/// network from [`sorting_network`]. The values must not be NaN. Sorting the same values
/// gives the same sequence whatever the algorithm, so this equals a per-pixel sort.
pub(super) fn sort_lanes(cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    if let Ok(rows) = <&mut [[f32; LANES]; 24]>::try_from(&mut *cols) {
        // The default 24 views: the fixed network (any sorting network sorts the same). With
        // AVX2, [`static_depth_row`] sorts them in vector registers instead.
        apply_network_24(rows, compare_exchange);
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        unsafe { sort_lanes_avx2(avx2, cols, network) };
        return;
    }
    sort_lanes_body(cols, network);
}

/// [`sort_lanes_body`] compiled for AVX2 (8 lanes of `f32` per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sort_lanes_avx2(_: dynapix_simd::Avx2, cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    sort_lanes_body(cols, network);
}

/// The 24-row network on `ymm` registers. `min(b, a)` is `b < a ? b : a` and `max(a, b)` is
/// `a > b ? a : b`, the selection of [`compare_exchange`] (for NaN too), so the same bits.
/// Inlined into the kernels (24 rows fit in the 32 registers of AVX-512VL; with AVX2's 16
/// some spill); the token proves that the AVX intrinsics may run.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn network_24_ymm(_: dynapix_simd::Avx2, v: &mut [std::arch::x86_64::__m256; 24]) {
    use std::arch::x86_64::{_mm256_max_ps, _mm256_min_ps};
    // SAFETY: the token proves the CPU has AVX.
    apply_network_24(v, |a, b| unsafe {
        (_mm256_min_ps(b, a), _mm256_max_ps(a, b))
    });
}

#[inline(always)]
fn sort_lanes_body(cols: &mut [[f32; LANES]], network: &[(usize, usize)]) {
    for &(i, j) in network {
        let (Some(&a), Some(&b)) = (cols.get(i), cols.get(j)) else {
            continue;
        };
        let mut lo = a;
        let mut hi = b;
        for l in 0..LANES {
            let swap = b[l] < a[l];
            lo[l] = if swap { b[l] } else { a[l] };
            hi[l] = if swap { a[l] } else { b[l] };
        }
        cols[i] = lo;
        cols[j] = hi;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::static_depth::fixtures::*;

    #[test]
    fn the_network_for_any_number_of_rows_sorts_every_lane() {
        let mut st = 7u64;
        for n in 1usize..=40 {
            let net = sorting_network_for(n);
            assert!(net.iter().all(|&(i, j)| i < j && j < n));
            for _ in 0..100 {
                let mut cols: Vec<[f32; LANES]> = (0..n)
                    .map(|_| {
                        std::array::from_fn(|_| match lcg(&mut st) % 8 {
                            0 => f32::INFINITY,
                            _ => (lcg(&mut st) % 30) as f32 * 0.1,
                        })
                    })
                    .collect();
                let mut want = cols.clone();
                sort_lanes(&mut cols, &net);
                for l in 0..LANES {
                    let mut lane: Vec<f32> = want.iter().map(|c| c[l]).collect();
                    lane.sort_unstable_by(f32::total_cmp);
                    for (c, v) in want.iter_mut().zip(lane) {
                        c[l] = v;
                    }
                }
                assert_eq!(cols, want, "n {n}");
            }
        }
        // The pruned network is smaller (24 views: 132 pairs instead of 191).
        assert_eq!(sorting_network_for(24).len(), 132);
        assert_eq!(sorting_network(32).len(), 191);
    }

    #[test]
    fn fixed_network_is_batchers() {
        assert_eq!(NETWORK_24.to_vec(), sorting_network_for(24));
    }

    #[test]
    fn the_fixed_network_sorts_like_the_loop_over_its_pairs() {
        let net = sorting_network_for(24);
        let mut st = 11u64;
        for _ in 0..500 {
            let cols: Vec<[f32; LANES]> = (0..24)
                .map(|_| {
                    std::array::from_fn(|_| match lcg(&mut st) % 6 {
                        0 => f32::INFINITY,
                        _ => (lcg(&mut st) % 40) as f32 * 0.07,
                    })
                })
                .collect();
            let mut want = cols.clone();
            sort_lanes_body(&mut want, &net);
            let bits = |c: &[[f32; LANES]]| -> Vec<u32> {
                c.iter().flatten().map(|v| v.to_bits()).collect()
            };
            // The straight-line network and the dispatching entry point (the vector-register
            // builds are compared in `rows_of_24_views_equal_the_generic_rows`).
            let mut v: [[f32; LANES]; 24] = std::array::from_fn(|r| cols[r]);
            apply_network_24(&mut v, compare_exchange);
            assert_eq!(bits(&v), bits(&want));
            let mut c = cols.clone();
            sort_lanes(&mut c, &net);
            assert_eq!(bits(&c), bits(&want));
        }
    }

    #[test]
    fn the_sorting_network_sorts_every_lane() {
        let mut st = 5u64;
        for n in [1usize, 2, 4, 8, 16, 32, 64] {
            let net = sorting_network(n);
            // 0-1 principle for the small ones, random values with ties for all.
            if n <= 16 {
                for bits in 0u32..(1 << n) {
                    let mut cols: Vec<[f32; LANES]> =
                        (0..n).map(|r| [((bits >> r) & 1) as f32; LANES]).collect();
                    sort_lanes(&mut cols, &net);
                    assert!(
                        cols.windows(2).all(|w| w[0][0] <= w[1][0]),
                        "n {n} bits {bits}"
                    );
                }
            }
            for _ in 0..200 {
                let mut cols: Vec<[f32; LANES]> = (0..n)
                    .map(|_| {
                        let mut c = [0.0; LANES];
                        for v in &mut c {
                            *v = match lcg(&mut st) % 8 {
                                0 => f32::INFINITY,
                                k => (lcg(&mut st) % 50) as f32 * 0.1 * k as f32,
                            };
                        }
                        c
                    })
                    .collect();
                let mut want: Vec<Vec<u32>> = (0..LANES)
                    .map(|l| {
                        let mut v: Vec<f32> = cols.iter().map(|c| c[l]).collect();
                        v.sort_unstable_by(f32::total_cmp);
                        v.into_iter().map(f32::to_bits).collect()
                    })
                    .collect();
                sort_lanes(&mut cols, &net);
                for (l, want) in want.iter_mut().enumerate() {
                    let got: Vec<u32> = cols.iter().map(|c| c[l].to_bits()).collect();
                    assert_eq!(&got, want, "n {n} lane {l}");
                }
            }
        }
    }
}
