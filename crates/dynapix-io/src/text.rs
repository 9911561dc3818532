//! Line splitting shared by the text parsers, following the TUM tools' `read_file_list`:
//! lines starting with `#` are comments, commas and tabs separate fields like spaces, empty
//! lines are skipped. Line numbers are 1-based and refer to the original file.

use std::path::Path;

use crate::error::{IoError, Result};

/// A non-comment, non-empty line: its 1-based number and its fields.
pub(crate) struct DataLine<'a> {
    /// 1-based line number in the file.
    pub no: usize,
    /// Whitespace/comma/tab separated fields.
    pub fields: Vec<&'a str>,
}

/// The data lines of `text` (comments and blank lines dropped, `\r` tolerated).
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = DataLine<'_>> {
    text.split('\n').enumerate().filter_map(|(i, line)| {
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            return None;
        }
        let fields = trimmed
            .split([' ', ',', '\t', '\r'])
            .filter(|f| !f.is_empty())
            .collect();
        Some(DataLine { no: i + 1, fields })
    })
}

/// Reads a whole text file, mapping failures to [`IoError::Io`] naming the file.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))
}

/// Parses a finite `f64` field; `what` names the column in the error.
pub(crate) fn parse_f64(path: &Path, line: usize, field: &str, what: &str) -> Result<f64> {
    match field.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(IoError::parse(
            path,
            line,
            format!("{what}: expected a finite number, got `{field}`"),
        )),
        Err(_) => Err(IoError::parse(
            path,
            line,
            format!("{what}: expected a number, got `{field}`"),
        )),
    }
}

/// Errors unless `fields` has exactly `n` entries; `layout` describes the expected columns.
pub(crate) fn expect_columns(
    path: &Path,
    line: &DataLine<'_>,
    n: usize,
    layout: &str,
) -> Result<()> {
    if line.fields.len() == n {
        Ok(())
    } else {
        Err(IoError::parse(
            path,
            line.no,
            format!("expected {n} columns ({layout}), got {}", line.fields.len()),
        ))
    }
}
