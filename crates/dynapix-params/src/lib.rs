//! Range checks of the parameter structs of the dynapix crates.
//!
//! Every parameter struct that a configuration file can set implements [`Validate`]: it
//! checks each of its numbers against a documented range before any work starts, and nested
//! structs are checked through [`nested`], which puts the struct's key in front of the
//! error's key. The configuration of a run (`dynapix::Config`) checks its sections the same
//! way, so an error names the whole key path (`slam.params.tracking.pose.rounds`) and the
//! range (`must lie in [1, 100], got 1000000000000`).
//!
//! Counts are bounded by what memory and time allow (a histogram of 10¹² bins or 10¹²
//! optimisation rounds is refused, not attempted); probabilities lie in [0, 1]; thresholds,
//! ratios and scales are positive and finite. NaN is outside every range.

#![forbid(unsafe_code)]
#![deny(missing_docs)]

use std::fmt::Display;

/// A parameter outside its valid range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{key} {message}")]
pub struct InvalidParam {
    /// Key path of the parameter, relative to the struct that was validated
    /// (`tracking.pose.rounds`).
    pub key: String,
    /// What is wrong, with the allowed range and the value (`must lie in [1, 100], got 0`).
    pub message: String,
}

impl InvalidParam {
    /// An error for `key`.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            message: message.into(),
        }
    }

    /// The same error seen from the struct that holds this one under `prefix`:
    /// `rounds` under `pose` becomes `pose.rounds`. An empty prefix changes nothing.
    pub fn under(mut self, prefix: &str) -> Self {
        if !prefix.is_empty() {
            self.key = if self.key.is_empty() {
                prefix.to_string()
            } else {
                format!("{prefix}.{}", self.key)
            };
        }
        self
    }
}

/// What every check returns.
pub type Checked = Result<(), InvalidParam>;

/// A parameter struct that checks its own values.
pub trait Validate {
    /// Checks every value against its documented range; the error names the key relative to
    /// this struct.
    fn validate(&self) -> Checked;
}

/// Validates `value`, a struct held under `key`, naming errors `key.<its key>`.
pub fn nested<T: Validate + ?Sized>(key: &str, value: &T) -> Checked {
    value.validate().map_err(|e| e.under(key))
}

/// `lo ≤ value ≤ hi` (integers and floats; NaN is refused).
pub fn range<T: PartialOrd + Display + Copy>(key: &str, value: T, lo: T, hi: T) -> Checked {
    if value >= lo && value <= hi {
        Ok(())
    } else {
        Err(InvalidParam::new(
            key,
            format!("must lie in [{lo}, {hi}], got {value}"),
        ))
    }
}

/// `lo < value ≤ hi` (floats: a positive threshold is `above(key, v, 0.0, max)`).
pub fn above<T: PartialOrd + Display + Copy>(key: &str, value: T, lo: T, hi: T) -> Checked {
    if value > lo && value <= hi {
        Ok(())
    } else {
        Err(InvalidParam::new(
            key,
            format!("must lie in ({lo}, {hi}], got {value}"),
        ))
    }
}

/// `lo ≤ value < hi`.
pub fn below<T: PartialOrd + Display + Copy>(key: &str, value: T, lo: T, hi: T) -> Checked {
    if value >= lo && value < hi {
        Ok(())
    } else {
        Err(InvalidParam::new(
            key,
            format!("must lie in [{lo}, {hi}), got {value}"),
        ))
    }
}

/// A probability or a fraction: `0 ≤ value ≤ 1`.
pub fn probability<T: PartialOrd + Display + Copy + From<u8>>(key: &str, value: T) -> Checked {
    range(key, value, T::from(0), T::from(1))
}

/// [`range`] for every element of a list, naming the element (`offsets[2]`), and a length
/// in `[min_len, max_len]`.
pub fn each<T: PartialOrd + Display + Copy>(
    key: &str,
    values: &[T],
    (min_len, max_len): (usize, usize),
    lo: T,
    hi: T,
) -> Checked {
    range(key, values.len(), min_len, max_len)
        .map_err(|e| InvalidParam::new(key, format!("length {}", e.message)))?;
    for (i, &v) in values.iter().enumerate() {
        range(&format!("{key}[{i}]"), v, lo, hi)?;
    }
    Ok(())
}

/// [`range`] for an optional value (`None` passes).
pub fn optional<T: PartialOrd + Display + Copy>(
    key: &str,
    value: Option<T>,
    lo: T,
    hi: T,
) -> Checked {
    value.map_or(Ok(()), |v| range(key, v, lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Inner {
        rounds: usize,
        ratio: f32,
    }

    impl Validate for Inner {
        fn validate(&self) -> Checked {
            range("rounds", self.rounds, 1, 100)?;
            probability("ratio", self.ratio)
        }
    }

    struct Outer {
        pose: Inner,
        offsets: Vec<i64>,
        chi2: f64,
    }

    impl Validate for Outer {
        fn validate(&self) -> Checked {
            nested("pose", &self.pose)?;
            each("offsets", &self.offsets, (1, 8), -30, 30)?;
            above("chi2", self.chi2, 0.0, 1e6)
        }
    }

    fn ok() -> Outer {
        Outer {
            pose: Inner {
                rounds: 4,
                ratio: 0.5,
            },
            offsets: vec![-1, 1],
            chi2: 5.991,
        }
    }

    #[test]
    fn errors_name_the_key_path_the_range_and_the_value() {
        ok().validate().unwrap();
        let mut o = ok();
        o.pose.rounds = 1_000_000_000_000;
        let e = nested("tracking", &o).unwrap_err().to_string();
        assert_eq!(
            e,
            "tracking.pose.rounds must lie in [1, 100], got 1000000000000"
        );
        let mut o = ok();
        o.pose.ratio = f32::NAN;
        assert_eq!(
            o.validate().unwrap_err().to_string(),
            "pose.ratio must lie in [0, 1], got NaN"
        );
        let mut o = ok();
        o.chi2 = 0.0;
        assert_eq!(
            o.validate().unwrap_err().to_string(),
            "chi2 must lie in (0, 1000000], got 0"
        );
        o.chi2 = f64::INFINITY;
        assert!(o.validate().is_err());
        let mut o = ok();
        o.offsets = vec![1, 31];
        assert_eq!(
            o.validate().unwrap_err().to_string(),
            "offsets[1] must lie in [-30, 30], got 31"
        );
        o.offsets.clear();
        assert_eq!(
            o.validate().unwrap_err().to_string(),
            "offsets length must lie in [1, 8], got 0"
        );
        assert!(below("x", 1.0, 0.0, 1.0).is_err() && below("x", 0.0, 0.0, 1.0).is_ok());
        assert!(optional("x", None::<u32>, 1, 2).is_ok());
        assert!(optional("x", Some(3u32), 1, 2).is_err());
        assert_eq!(InvalidParam::new("", "bad").under("a").key, "a");
    }
}
