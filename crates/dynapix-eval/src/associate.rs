//! Timestamp association of two trajectories exactly like the TUM `associate.py` used by the
//! reference `eval.py` (spec §4.2): every pair with |a − (b + offset)| < max_diff is a
//! candidate, candidates are sorted by that difference and taken greedily one-to-one.
//! Optionally, pairs with a stamp outside [start − 1 s, end + 1 s] are skipped, as `eval.py`
//! does.
//!
//! Unlike the Python tool (which builds all n·m candidates), `dynapix_io::associate` finds candidates with a
//! binary search on the sorted second list, so 100 000-pose trajectories associate in
//! milliseconds; the result is identical, ties included (sorted by difference, then first
//! stamp, then second stamp, as Python sorts tuples).

/// Association parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct AssocParams {
    /// Maximum |a − (b + offset)|, seconds (strict). TUM default 0.02.
    pub max_diff: f64,
    /// Added to the second list's stamps before comparing, seconds.
    pub offset: f64,
    /// Optional evaluation window `[start, end]`; pairs with a stamp outside
    /// `[start − window_margin, end + window_margin]` are skipped.
    pub window: Option<(f64, f64)>,
    /// Tolerance around the window, seconds (`eval.py`: 1.0, written `10e-1`).
    pub window_margin: f64,
}

impl Default for AssocParams {
    fn default() -> Self {
        Self {
            max_diff: 0.02,
            offset: 0.0,
            window: None,
            window_margin: 1.0,
        }
    }
}

/// Associates stamps of `first` with stamps of `second`; returns index pairs `(i, j)` sorted by
/// `first[i]`. Input order does not matter; NaN stamps never match.
pub fn associate(first: &[f64], second: &[f64], params: &AssocParams) -> Vec<(usize, usize)> {
    // The pairing rule itself is `dynapix_io::associate` (the TUM tool's greedy rule); this
    // layer only adds the evaluation window and drops non-finite stamps first.
    let in_window = |t: f64| match params.window {
        Some((s, e)) => t >= s - params.window_margin && t <= e + params.window_margin,
        None => true,
    };
    let keep = |ts: &[f64]| -> Vec<usize> {
        (0..ts.len())
            .filter(|&i| ts[i].is_finite() && in_window(ts[i]))
            .collect()
    };
    let (kept_first, kept_second) = (keep(first), keep(second));
    let a: Vec<f64> = kept_first.iter().map(|&i| first[i]).collect();
    let b: Vec<f64> = kept_second.iter().map(|&j| second[j]).collect();
    dynapix_io::associate(&a, &b, params.offset, params.max_diff)
        .into_iter()
        .map(|(i, j)| (kept_first[i], kept_second[j]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Straightforward O(n·m) transcription of `associate.py`, the oracle for the fast version.
    fn brute(first: &[f64], second: &[f64], p: &AssocParams) -> Vec<(usize, usize)> {
        let mut c = Vec::new();
        for (i, &a) in first.iter().enumerate() {
            for (j, &b) in second.iter().enumerate() {
                let d = (a - (b + p.offset)).abs();
                let ok = |t: f64| match p.window {
                    Some((s, e)) => t >= s - p.window_margin && t <= e + p.window_margin,
                    None => true,
                };
                if d < p.max_diff && ok(a) && ok(b) {
                    c.push((d, a, b, i, j));
                }
            }
        }
        c.sort_by(|x, y| {
            x.0.total_cmp(&y.0)
                .then(x.1.total_cmp(&y.1))
                .then(x.2.total_cmp(&y.2))
        });
        let (mut uf, mut us) = (vec![false; first.len()], vec![false; second.len()]);
        let mut m = Vec::new();
        for (_, _, _, i, j) in c {
            if !uf[i] && !us[j] {
                uf[i] = true;
                us[j] = true;
                m.push((i, j));
            }
        }
        m.sort_by(|x, y| first[x.0].total_cmp(&first[y.0]));
        m
    }

    #[test]
    fn greedy_takes_the_globally_closest_pair_first() {
        // 1.008–1.006 (2 ms) is taken first, so 1.000 falls back to 0.990 (10 ms) although
        // 1.006 is nearer to it.
        let first = [1.000, 1.008];
        let second = [1.006, 0.990];
        let m = associate(&first, &second, &AssocParams::default());
        assert_eq!(m, vec![(0, 1), (1, 0)]);
    }

    #[test]
    fn strict_threshold_offset_and_window() {
        // Binary fractions, so the differences are exact.
        let first = [10.0, 20.0, 30.0];
        let second = [10.25, 19.5, 29.875];
        let p = AssocParams {
            max_diff: 0.25,
            ..AssocParams::default()
        };
        assert_eq!(associate(&first, &second, &p), vec![(2, 2)]);
        let p = AssocParams {
            max_diff: 0.25,
            offset: 0.5,
            ..AssocParams::default()
        };
        assert_eq!(associate(&first, &second, &p), vec![(1, 1)]);
        let p = AssocParams {
            max_diff: 0.3,
            window: Some((0.0, 18.0)),
            ..AssocParams::default()
        };
        assert_eq!(associate(&first, &second, &p), vec![(0, 0)]);
    }

    proptest! {
        #[test]
        fn prop_matches_brute_force(
            a in prop::collection::vec(0u32..400, 0..40),
            b in prop::collection::vec(0u32..400, 0..40),
            offset in -2i32..3,
            win in prop::option::of((0u32..20, 20u32..40)),
        ) {
            // Stamps on a 10 ms grid (lots of ties and boundary cases).
            let first: Vec<f64> = a.iter().map(|&v| v as f64 * 0.01 + 100.0).collect();
            let second: Vec<f64> = b.iter().map(|&v| v as f64 * 0.01 + 100.0).collect();
            let p = AssocParams {
                offset: offset as f64 * 0.01,
                window: win.map(|(s, e)| (100.0 + s as f64 * 0.1, 100.0 + e as f64 * 0.1)),
                window_margin: 0.5,
                ..AssocParams::default()
            };
            prop_assert_eq!(associate(&first, &second, &p), brute(&first, &second, &p));
        }
    }
}
