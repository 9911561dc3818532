//! The one median of the workspace, in two forms: [`upper_median_by`], the element of rank
//! `len/2` found by selection in O(n) (the form the algorithms use: for an even count it is
//! the upper of the two middle values), and [`median`], the mean of the two middle values for
//! an even count (the form reports use).

use std::cmp::Ordering;

/// The element of rank `len/2` of `values` under `cmp` (the upper median), found by
/// selection in O(n); `values` is reordered. `None` when `values` is empty.
pub fn upper_median_by<T: Copy>(
    values: &mut [T],
    cmp: impl FnMut(&T, &T) -> Ordering,
) -> Option<T> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    Some(*values.select_nth_unstable_by(mid, cmp).1)
}

/// The median of `values` (the mean of the two middle values for an even count), ordered by
/// `f64::total_cmp`; `values` is reordered. `None` when `values` is empty.
pub fn median(values: &mut [f64]) -> Option<f64> {
    let upper = upper_median_by(values, f64::total_cmp)?;
    let n = values.len();
    if n % 2 == 1 {
        return Some(upper);
    }
    // After the selection every value left of the middle is ≤ it: the lower middle value is
    // their maximum.
    let lower = values[..n / 2].iter().copied().max_by(f64::total_cmp)?;
    Some(0.5 * (lower + upper))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upper_median_is_the_element_of_rank_half_the_length() {
        assert_eq!(
            upper_median_by(&mut [3.0f32, 1.0, 2.0], f32::total_cmp),
            Some(2.0)
        );
        assert_eq!(upper_median_by(&mut [4u16, 1, 3, 2], u16::cmp), Some(3));
        assert_eq!(upper_median_by(&mut [] as &mut [f32], f32::total_cmp), None);
    }

    #[test]
    fn median_averages_the_two_middle_values() {
        assert_eq!(median(&mut [5.0, 1.0, 3.0]), Some(3.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&mut [7.0]), Some(7.0));
        assert_eq!(median(&mut []), None);
        // Same as sorting and averaging, on values with repeats.
        let v = [9.0, 2.0, 2.0, 7.0, 5.0, 5.0, 1.0, 8.0];
        let mut s = v;
        s.sort_by(f64::total_cmp);
        assert_eq!(median(&mut v.clone()), Some(0.5 * (s[3] + s[4])));
    }
}
