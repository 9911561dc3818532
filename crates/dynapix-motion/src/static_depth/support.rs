//! The farthest depth that enough views agree on, refined to the median of those views, over
//! sorted columns of [`LANES`] pixels.

use super::network::LANES;
use super::params::StaticDepthParams;

/// The farthest value that at least `min_support` values agree with (within `tol`), refined
/// to the median of the values agreeing with it; `NaN` when none is supported.
#[cfg(test)]
fn farthest_supported(vals: &mut [f32], params: &StaticDepthParams) -> f32 {
    vals.sort_unstable_by(|a, b| b.total_cmp(a));
    farthest_supported_in_sorted(vals, params)
}

/// [`farthest_supported`] of the `n` values `a(0) ≤ … ≤ a(n − 1)`, read in place: the same
/// scan as [`farthest_supported_in_sorted`] from the far end, so the same result bit for bit
/// (test `ascending_scan_equals_the_descending_scan`).
#[inline(always)]
fn farthest_supported_ascending(
    a: impl Fn(usize) -> f32,
    n: usize,
    params: &StaticDepthParams,
) -> f32 {
    if n < params.min_support {
        return f32::NAN;
    }
    for k in (0..n).rev() {
        let v = a(k);
        let tol = params.tol(v);
        // The values within tol of v are a contiguous run lo..=hi around k.
        let mut hi = k;
        while hi + 1 < n && a(hi + 1) - v < tol {
            hi += 1;
        }
        let mut lo = k;
        while lo > 0 && v - a(lo - 1) < tol {
            lo -= 1;
        }
        let m = hi - lo + 1;
        if m >= params.min_support {
            // The median of the run in descending order, as `median_sorted_desc`.
            return if m % 2 == 1 {
                a(hi - m / 2)
            } else {
                0.5 * (a(hi - m / 2 + 1) + a(hi - m / 2))
            };
        }
    }
    f32::NAN
}

/// [`farthest_supported_ascending`] of every lane of `cols`, sorted ascending per lane with
/// the views without a surface (+∞) last. Most pixels are decided at their farthest value:
/// the run of values within `tol` below it is counted for all lanes at once (the test
/// `v − a(j) < tol` holds on a contiguous run below the top because rounded subtraction is
/// monotone, so the count is the run's length, as the step-by-step scan finds it) and the
/// median taken from it; only lanes whose farthest value lacks support scan further, one at
/// a time. The same values bit for bit (test `lane_scan_equals_the_scan_of_each_lane`).
#[inline(always)]
pub(super) fn farthest_supported_lanes(
    cols: &[[f32; LANES]],
    params: &StaticDepthParams,
) -> [f32; LANES] {
    // Finite values per lane (they come first).
    let mut n_fin = [0u32; LANES];
    for c in cols {
        for l in 0..LANES {
            n_fin[l] += u32::from(c[l].is_finite());
        }
    }
    let mut top = [0f32; LANES];
    let mut tol = [0f32; LANES];
    for l in 0..LANES {
        if let Some(k) = (n_fin[l] as usize).checked_sub(1) {
            top[l] = cols[k][l];
            tol[l] = params.tol(top[l]);
        }
    }
    let below = run_below_top(cols, &n_fin, &top, &tol);
    let mut out = [f32::NAN; LANES];
    for l in 0..LANES {
        let n = n_fin[l] as usize;
        if n < params.min_support {
            continue;
        }
        let (hi, m) = (n - 1, below[l] as usize + 1);
        out[l] = if m >= params.min_support {
            // The median of the run, as `farthest_supported_ascending`.
            if m % 2 == 1 {
                cols[hi - m / 2][l]
            } else {
                0.5 * (cols[hi - m / 2 + 1][l] + cols[hi - m / 2][l])
            }
        } else {
            farthest_supported_ascending(|k| cols[k][l], n, params)
        };
    }
    out
}

/// Per lane, the number of values at rows `j < n_fin − 1` with `top − a(j) < tol`,
/// compiled for AVX2 when the CPU has it (a count: the same in every build).
fn run_below_top(
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = dynapix_simd::Avx2::detect() {
        // SAFETY: the token proves the CPU has AVX2.
        return unsafe { run_below_top_avx2(avx2, cols, n_fin, top, tol) };
    }
    run_below_top_body(cols, n_fin, top, tol)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn run_below_top_avx2(
    _: dynapix_simd::Avx2,
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    run_below_top_body(cols, n_fin, top, tol)
}

#[inline(always)]
fn run_below_top_body(
    cols: &[[f32; LANES]],
    n_fin: &[u32; LANES],
    top: &[f32; LANES],
    tol: &[f32; LANES],
) -> [u32; LANES] {
    let mut count = [0u32; LANES];
    for (j, c) in cols.iter().enumerate() {
        let j = j as u32;
        for l in 0..LANES {
            let inside = j + 1 < n_fin[l];
            let near = top[l] - c[l] < tol[l];
            count[l] += u32::from(inside & near);
        }
    }
    count
}

/// [`farthest_supported`] of values already sorted descending.
#[cfg(test)]
fn farthest_supported_in_sorted(vals: &[f32], params: &StaticDepthParams) -> f32 {
    if vals.len() < params.min_support {
        return f32::NAN;
    }
    for (k, &v) in vals.iter().enumerate() {
        let tol = params.tol(v);
        // Sorted descending: the values within tol of v are a contiguous run around k.
        let lo = vals[..k].iter().rev().take_while(|&&x| x - v < tol).count();
        let hi = vals[k + 1..].iter().take_while(|&&x| v - x < tol).count();
        if lo + hi + 1 >= params.min_support {
            let run = &vals[k - lo..=k + hi];
            return median_sorted_desc(run);
        }
    }
    f32::NAN
}

#[cfg(test)]
fn median_sorted_desc(run: &[f32]) -> f32 {
    let m = run.len();
    if m % 2 == 1 {
        run[m / 2]
    } else {
        0.5 * (run[m / 2 - 1] + run[m / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::static_depth::fixtures::*;

    #[test]
    fn farthest_supported_ignores_a_single_far_outlier() {
        let p = params();
        let mut v = vec![2.0, 2.01, 1.99, 1.0, 1.01, 5.0];
        let s = farthest_supported(&mut v, &p);
        assert!((s - 2.0).abs() < 0.011, "{s}");
        let mut v = vec![1.0, 5.0];
        assert!(farthest_supported(&mut v, &p).is_nan());
    }

    /// A depth from one of four clusters (with close values and exact ties) or an outlier.
    fn cluster_depth(st: &mut u64) -> f32 {
        let c = (lcg(st) % 4) as f32;
        match lcg(st) % 8 {
            0 => 0.3 + (lcg(st) % 8000) as f32 * 0.001,
            1 => 1.0 + c,
            _ => 1.0 + c + (lcg(st) % 100) as f32 * 0.0007,
        }
    }

    #[test]
    fn ascending_scan_equals_the_descending_scan() {
        let p = StaticDepthParams::default();
        let mut st = 11u64;
        let mut supported = 0;
        for n in 0..40 {
            for _ in 0..200 {
                // Clusters of nearby depths with outliers and exact ties.
                let mut v: Vec<f32> = (0..n).map(|_| cluster_depth(&mut st)).collect();
                v.sort_unstable_by(f32::total_cmp);
                let want = farthest_supported(&mut v.clone(), &p);
                let got = farthest_supported_ascending(|k| v[k], v.len(), &p);
                assert_eq!(got.to_bits(), want.to_bits(), "{v:?}");
                supported += usize::from(want.is_finite());
            }
        }
        assert!(supported > 1000, "{supported}");
    }

    #[test]
    #[allow(clippy::needless_range_loop)] // lane l of every row is written
    fn lane_scan_equals_the_scan_of_each_lane() {
        let mut st = 5u64;
        let mut decided_at_top = 0;
        let mut scanned = 0;
        for rows in [1, 3, 8, 17, 24] {
            for min_support in [1, 3, 6] {
                let p = StaticDepthParams {
                    min_support,
                    ..StaticDepthParams::default()
                };
                for _ in 0..300 {
                    let mut cols = vec![[f32::INFINITY; LANES]; rows];
                    for l in 0..LANES {
                        let n = (lcg(&mut st) as usize) % (rows + 1);
                        let mut v: Vec<f32> = (0..n).map(|_| cluster_depth(&mut st)).collect();
                        v.sort_unstable_by(f32::total_cmp);
                        for (k, x) in v.iter().enumerate() {
                            cols[k][l] = *x;
                        }
                    }
                    let got = farthest_supported_lanes(&cols, &p);
                    for l in 0..LANES {
                        let n = cols.partition_point(|c| c[l].is_finite());
                        let want = farthest_supported_ascending(|k| cols[k][l], n, &p);
                        assert_eq!(got[l].to_bits(), want.to_bits(), "lane {l} of {cols:?}");
                        if n >= min_support && want.is_finite() {
                            let top = cols[n - 1][l];
                            let support = (0..n).filter(|&k| top - cols[k][l] < p.tol(top)).count();
                            if support >= min_support {
                                decided_at_top += 1;
                            } else {
                                scanned += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(
            decided_at_top > 1000 && scanned > 100,
            "{decided_at_top} {scanned}"
        );
    }
}
