//! TUM RGB-D text lists and their association (spec §5.1, §4.2).
//!
//! - `rgb.txt` / `depth.txt`: `timestamp relative/path.png` per line, `#` comments.
//! - [`associate`]: the exact rule of the TUM `associate.py`: every pair with
//!   |a − (b + offset)| < max_diff is a candidate, candidates are sorted by (difference, a, b)
//!   and taken greedily one-to-one; the result is sorted by the first timestamp.
//! - Association files: `t_rgb rgb_path t_depth depth_path` (4 columns), as written by
//!   `associate.py rgb.txt depth.txt`; GRADE-style names (`rgb/12.png`, `/rgb/12.png`) are
//!   accepted, see [`resolve_path`].
//!
//! Like the TUM tools, commas and tabs separate fields. Timestamps must not decrease; a
//! repeated timestamp keeps the later line (the TUM tools store the lists in a dictionary).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::atomic::write_atomic;
use crate::error::{IoError, Result};
use crate::text::{data_lines, expect_columns, parse_f64, read_text};

/// Default maximal time difference (s) of an association, as in `associate.py`.
pub const DEFAULT_MAX_DIFF: f64 = 0.02;

/// One line of `rgb.txt` or `depth.txt`: a timestamp and the image path as written in the
/// file (relative to the sequence folder; resolve it with [`resolve_path`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ListEntry {
    /// Timestamp in seconds.
    pub t: f64,
    /// Image path as written in the list.
    pub path: String,
}

/// One rgb/depth pair of an association file, paths as written in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct Association {
    /// Timestamp of the colour image (the frame time).
    pub t_rgb: f64,
    /// Colour image path as written in the file.
    pub rgb: String,
    /// Timestamp of the depth image.
    pub t_depth: f64,
    /// Depth image path as written in the file.
    pub depth: String,
}

/// Reads an image list (`rgb.txt`, `depth.txt`): two columns `timestamp path`.
pub fn read_list(path: impl AsRef<Path>) -> Result<Vec<ListEntry>> {
    let path = path.as_ref();
    parse_list(&read_text(path)?, path)
}

/// Parses image-list text; `path` is only used in error messages.
pub fn parse_list(text: &str, path: &Path) -> Result<Vec<ListEntry>> {
    let mut out: Vec<ListEntry> = Vec::new();
    let mut last_line = 0;
    for line in data_lines(text) {
        expect_columns(path, &line, 2, "timestamp path")?;
        let t = parse_f64(path, line.no, line.fields[0], "timestamp")?;
        if out.last().is_some_and(|l| l.t == t) {
            // In an image list a repeated timestamp would silently drop a frame.
            return Err(IoError::parse(
                path,
                line.no,
                format!(
                    "timestamp {} repeats line {last_line}: every image needs its own time",
                    line.fields[0]
                ),
            ));
        }
        last_line = line.no;
        let entry = ListEntry {
            t,
            path: line.fields[1].to_string(),
        };
        push_sorted(&mut out, entry, |e| e.t, path, line.no, line.fields[0])?;
    }
    Ok(out)
}

/// Appends `item` keeping timestamps sorted: a decrease is an error, an equal timestamp
/// replaces the previous item (TUM dictionary semantics).
fn push_sorted<T>(
    out: &mut Vec<T>,
    item: T,
    time: impl Fn(&T) -> f64,
    path: &Path,
    line: usize,
    field: &str,
) -> Result<()> {
    match out.last_mut() {
        Some(last) if time(&item) < time(last) => Err(IoError::parse(
            path,
            line,
            format!("timestamps not sorted: {field} comes after {}", time(last)),
        )),
        Some(last) if time(&item) == time(last) => {
            *last = item;
            Ok(())
        }
        _ => {
            out.push(item);
            Ok(())
        }
    }
}

/// The text of an image list with a TUM-style 3-line header; `kind` is e.g. `"color images"`.
pub fn list_to_string(entries: &[ListEntry], kind: &str) -> String {
    let mut s = format!("# {kind}\n# written by dynapix\n# timestamp filename\n");
    for e in entries {
        let _ = writeln!(s, "{:.6} {}", e.t, e.path);
    }
    s
}

/// Errors unless `written` can stand as one column of a list: non-empty, no separator
/// (space, tab, comma, line break) and not starting with `#`.
fn check_column_path(path: &Path, what: &str, written: &str) -> Result<()> {
    if written.is_empty()
        || written.starts_with('#')
        || written.contains([' ', '\t', ',', '\n', '\r'])
    {
        return Err(IoError::invalid(
            path,
            format!(
                "{what} `{written}` cannot be written as one column (empty, separator or leading #)"
            ),
        ));
    }
    Ok(())
}

/// Errors unless `t` is finite and, when `strict`, above `prev` (else not below it).
fn check_time(path: &Path, i: usize, t: f64, prev: Option<f64>, strict: bool) -> Result<()> {
    let ordered = match prev {
        None => true,
        Some(p) if strict => t > p,
        Some(p) => t >= p,
    };
    if !t.is_finite() || !ordered {
        return Err(IoError::invalid(
            path,
            format!("entry {i}: timestamp {t} is not finite or out of order"),
        ));
    }
    Ok(())
}

/// Writes an image list atomically (see [`list_to_string`]). Refuses (writing nothing)
/// entries that would not read back: non-finite or decreasing timestamps, paths with
/// separators.
pub fn write_list(path: impl AsRef<Path>, entries: &[ListEntry], kind: &str) -> Result<()> {
    let path = path.as_ref();
    for (i, e) in entries.iter().enumerate() {
        let prev = i.checked_sub(1).map(|j| entries[j].t);
        check_time(path, i, e.t, prev, false)?;
        check_column_path(path, "image path", &e.path)?;
    }
    write_atomic(path, list_to_string(entries, kind).as_bytes())
}

/// Associates two timestamp lists exactly like the TUM `associate.py`: all pairs (i, j) with
/// `|first[i] − (second[j] + offset)| < max_diff`, sorted by (difference, first, second),
/// taken greedily so each index is used at most once. Returns index pairs sorted by
/// `first[i]`. The inputs need not be sorted; NaN timestamps never match.
pub fn associate(first: &[f64], second: &[f64], offset: f64, max_diff: f64) -> Vec<(usize, usize)> {
    // Candidates come from a sliding window over `second` in time order instead of the
    // O(n·m) double loop; the selection rule is unchanged.
    let mut order: Vec<usize> = (0..second.len()).collect();
    order.sort_by(|&x, &y| second[x].total_cmp(&second[y]));
    let shifted: Vec<f64> = order.iter().map(|&j| second[j] + offset).collect();
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, &a) in first.iter().enumerate() {
        // `a - b` decreases as b grows, so the matches form one contiguous run.
        let start = shifted.partition_point(|&b| a - b >= max_diff);
        for (k, &b) in shifted.iter().enumerate().skip(start) {
            let d = a - b;
            if d <= -max_diff || d.is_nan() {
                break;
            }
            if d.abs() < max_diff {
                candidates.push((d.abs(), i, order[k]));
            }
        }
    }
    candidates.sort_by(|x, y| {
        x.0.total_cmp(&y.0)
            .then(first[x.1].total_cmp(&first[y.1]))
            .then(second[x.2].total_cmp(&second[y.2]))
    });
    let mut used_first = vec![false; first.len()];
    let mut used_second = vec![false; second.len()];
    let mut matches = Vec::new();
    for (_, i, j) in candidates {
        if !used_first[i] && !used_second[j] {
            used_first[i] = true;
            used_second[j] = true;
            matches.push((i, j));
        }
    }
    matches.sort_by(|x, y| first[x.0].total_cmp(&first[y.0]).then(x.0.cmp(&y.0)));
    matches
}

/// Associates an rgb list with a depth list ([`associate`], depth shifted by `offset`).
pub fn associate_lists(
    rgb: &[ListEntry],
    depth: &[ListEntry],
    offset: f64,
    max_diff: f64,
) -> Vec<Association> {
    let a: Vec<f64> = rgb.iter().map(|e| e.t).collect();
    let b: Vec<f64> = depth.iter().map(|e| e.t).collect();
    associate(&a, &b, offset, max_diff)
        .into_iter()
        .map(|(i, j)| Association {
            t_rgb: rgb[i].t,
            rgb: rgb[i].path.clone(),
            t_depth: depth[j].t,
            depth: depth[j].path.clone(),
        })
        .collect()
}

/// Every rgb frame with the depth image nearest in time (within `max_diff`; a depth image
/// may serve several rgb frames; ties go to the earlier depth image). Unlike
/// [`associate_lists`] no rgb frame is dropped because its depth went to a neighbour, so a
/// tracking rate can be measured against the full rgb list.
pub fn associate_nearest(
    rgb: &[ListEntry],
    depth: &[ListEntry],
    max_diff: f64,
) -> Vec<Association> {
    rgb.iter()
        .filter_map(|r| {
            let d = depth
                .iter()
                .min_by(|a, b| (a.t - r.t).abs().total_cmp(&(b.t - r.t).abs()))?;
            ((d.t - r.t).abs() < max_diff).then(|| Association {
                t_rgb: r.t,
                rgb: r.path.clone(),
                t_depth: d.t,
                depth: d.path.clone(),
            })
        })
        .collect()
}

/// Reads a 4-column association file `t_rgb rgb_path t_depth depth_path`. The rgb
/// timestamps must strictly increase (each frame once).
pub fn read_associations(path: impl AsRef<Path>) -> Result<Vec<Association>> {
    let path = path.as_ref();
    parse_associations(&read_text(path)?, path)
}

/// Parses association text; `path` is only used in error messages.
pub fn parse_associations(text: &str, path: &Path) -> Result<Vec<Association>> {
    let mut out: Vec<Association> = Vec::new();
    for line in data_lines(text) {
        expect_columns(path, &line, 4, "t_rgb rgb_path t_depth depth_path")?;
        let f = &line.fields;
        let t_rgb = parse_f64(path, line.no, f[0], "rgb timestamp")?;
        let t_depth = parse_f64(path, line.no, f[2], "depth timestamp")?;
        if let Some(last) = out.last()
            && t_rgb <= last.t_rgb
        {
            return Err(IoError::parse(
                path,
                line.no,
                format!(
                    "rgb timestamps not strictly increasing: {} after {}",
                    f[0], last.t_rgb
                ),
            ));
        }
        out.push(Association {
            t_rgb,
            rgb: f[1].to_string(),
            t_depth,
            depth: f[3].to_string(),
        });
    }
    Ok(out)
}

/// The text of an association file (no header, timestamps with 6 decimals, like
/// `associate.py`).
pub fn associations_to_string(assoc: &[Association]) -> String {
    let mut s = String::with_capacity(assoc.len() * 90);
    for a in assoc {
        let _ = writeln!(s, "{:.6} {} {:.6} {}", a.t_rgb, a.rgb, a.t_depth, a.depth);
    }
    s
}

/// Writes an association file atomically (see [`associations_to_string`]). Refuses
/// (writing nothing) lines that would not read back: non-finite timestamps, rgb timestamps
/// not strictly increasing, paths with separators.
pub fn write_associations(path: impl AsRef<Path>, assoc: &[Association]) -> Result<()> {
    let path = path.as_ref();
    for (i, a) in assoc.iter().enumerate() {
        let prev = i.checked_sub(1).map(|j| assoc[j].t_rgb);
        check_time(path, i, a.t_rgb, prev, true)?;
        check_time(path, i, a.t_depth, None, false)?;
        check_column_path(path, "rgb path", &a.rgb)?;
        check_column_path(path, "depth path", &a.depth)?;
    }
    write_atomic(path, associations_to_string(assoc).as_bytes())
}

/// Resolves an image path from a list or association file against the sequence folder
/// `dir`. A relative path is joined to `dir`; a path with a leading `/` (GRADE-eval writes
/// `/rgb/12.png`) is taken as absolute only if that file exists, otherwise it is read
/// relative to `dir` with the slash dropped.
pub fn resolve_path(dir: &Path, written: &str) -> PathBuf {
    let p = Path::new(written);
    if p.is_absolute() {
        if p.exists() {
            return p.to_path_buf();
        }
        return dir.join(written.trim_start_matches('/'));
    }
    dir.join(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_keeps_every_rgb_frame_unlike_associate() {
        let e = |t: f64, p: &str| ListEntry {
            t,
            path: p.to_string(),
        };
        let rgb = [e(1.000, "r1"), e(1.010, "r2"), e(1.035, "r3"), e(2.0, "r4")];
        let depth = [e(1.004, "d1"), e(1.050, "d2")];
        let near = associate_nearest(&rgb, &depth, DEFAULT_MAX_DIFF);
        let got: Vec<(&str, &str)> = near
            .iter()
            .map(|a| (a.rgb.as_str(), a.depth.as_str()))
            .collect();
        // r1 and r2 share d1; r4 has no depth within 0.02 s.
        assert_eq!(got, [("r1", "d1"), ("r2", "d1"), ("r3", "d2")]);
        // associate.py gives d1 to r1 only and drops r2.
        let unique = associate_lists(&rgb, &depth, 0.0, DEFAULT_MAX_DIFF);
        let got: Vec<&str> = unique.iter().map(|a| a.rgb.as_str()).collect();
        assert_eq!(got, ["r1", "r3"]);
        assert_eq!(near[0].t_depth, 1.004);
    }

    use crate::testutil::data_dir;

    /// The literal O(n·m) algorithm of `associate.py`, to check the windowed version.
    fn associate_reference(a: &[f64], b: &[f64], offset: f64, max: f64) -> Vec<(usize, usize)> {
        let mut cand = Vec::new();
        for (i, &x) in a.iter().enumerate() {
            for (j, &y) in b.iter().enumerate() {
                let d = (x - (y + offset)).abs();
                if d < max {
                    cand.push((d, x, y, i, j));
                }
            }
        }
        cand.sort_by(|p, q| {
            p.0.total_cmp(&q.0)
                .then(p.1.total_cmp(&q.1))
                .then(p.2.total_cmp(&q.2))
        });
        let (mut ua, mut ub) = (vec![false; a.len()], vec![false; b.len()]);
        let mut m = Vec::new();
        for (_, _, _, i, j) in cand {
            if !ua[i] && !ub[j] {
                ua[i] = true;
                ub[j] = true;
                m.push((i, j));
            }
        }
        m.sort_by(|p, q| a[p.0].total_cmp(&a[q.0]));
        m
    }

    #[test]
    fn associate_is_greedy_one_to_one() {
        // 1.00 is closest to 1.005 (0.005); 1.01 then takes 1.025 (0.015); 1.5 has nothing.
        let a = [1.0, 1.01, 1.5];
        let b = [1.005, 1.025, 2.0];
        assert_eq!(associate(&a, &b, 0.0, 0.02), vec![(0, 0), (1, 1)]);
        // With an offset of +0.49, 1.5 matches 1.005+0.49 = 1.495 instead.
        assert_eq!(associate(&a, &b, 0.49, 0.02), vec![(2, 0)]);
        // Strict inequality: a difference of exactly max_diff is not a match.
        assert!(associate(&[1.0], &[1.5], 0.0, 0.5).is_empty());
        assert!(associate(&[f64::NAN], &[1.0], 0.0, 0.5).is_empty());
    }

    #[test]
    fn windowed_associate_matches_the_literal_algorithm() {
        // Deterministic jittered 30 Hz streams with gaps, unsorted second list.
        let mut s = 12345u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let a: Vec<f64> = (0..400)
            .map(|i| 100.0 + i as f64 / 30.0 + 0.01 * next())
            .collect();
        let mut b: Vec<f64> = (0..380)
            .map(|i| 100.0 + i as f64 / 29.0 + 0.03 * (next() - 0.5))
            .collect();
        b.swap(3, 200);
        b.swap(17, 5);
        for (offset, max) in [(0.0, 0.02), (0.01, 0.02), (-0.02, 0.05), (0.0, 0.001)] {
            assert_eq!(
                associate(&a, &b, offset, max),
                associate_reference(&a, &b, offset, max)
            );
        }
    }

    #[test]
    fn lists_and_associations_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let rgb = vec![
            ListEntry {
                t: 1.0,
                path: "rgb/1.000000.png".into(),
            },
            ListEntry {
                t: 1.033333,
                path: "rgb/1.033333.png".into(),
            },
        ];
        let p = dir.path().join("rgb.txt");
        write_list(&p, &rgb, "color images").unwrap();
        assert_eq!(read_list(&p).unwrap(), rgb);
        let depth = vec![
            ListEntry {
                t: 1.01,
                path: "depth/1.010000.png".into(),
            },
            ListEntry {
                t: 1.05,
                path: "depth/1.050000.png".into(),
            },
        ];
        let assoc = associate_lists(&rgb, &depth, 0.0, DEFAULT_MAX_DIFF);
        assert_eq!(assoc.len(), 2);
        assert_eq!(assoc[1].depth, "depth/1.050000.png");
        let p = dir.path().join("association.txt");
        write_associations(&p, &assoc).unwrap();
        assert_eq!(read_associations(&p).unwrap(), assoc);
        // Entries that could not be read back are refused and nothing is written.
        let q = dir.path().join("bad.txt");
        let mut spaced = assoc.clone();
        spaced[0].rgb = "rgb/a b.png".into();
        let e = write_associations(&q, &spaced).unwrap_err().to_string();
        assert!(e.contains("bad.txt") && e.contains("rgb/a b.png"), "{e}");
        let reversed: Vec<Association> = assoc.iter().rev().cloned().collect();
        assert!(write_associations(&q, &reversed).is_err());
        let mut nan = rgb.clone();
        nan[1].t = f64::NAN;
        assert!(write_list(&q, &nan, "x").is_err());
        assert!(!q.exists());
    }

    #[test]
    fn grade_style_names_and_resolution() {
        let text =
            "0.000000 /rgb/1.png 0.000000 /depth/1.png\n0.033333 rgb/2.png 0.033333 depth/2.png\n";
        let a = parse_associations(text, Path::new("rgbd_assoc.txt")).unwrap();
        assert_eq!(a.len(), 2);
        let dir = Path::new("/seq");
        assert_eq!(resolve_path(dir, &a[0].rgb), Path::new("/seq/rgb/1.png"));
        assert_eq!(
            resolve_path(dir, &a[1].depth),
            Path::new("/seq/depth/2.png")
        );
        let tmp = tempfile::tempdir().unwrap();
        let abs = tmp.path().join("x.png");
        std::fs::write(&abs, b"").unwrap();
        assert_eq!(resolve_path(dir, abs.to_str().unwrap()), abs);
    }

    #[test]
    fn bad_lists_and_associations_name_file_and_line() {
        let e = |r: Result<Vec<ListEntry>>| r.unwrap_err().to_string();
        let s = e(parse_list(
            "# h\n1.0 rgb/a.png\n1.1\n",
            Path::new("rgb.txt"),
        ));
        assert!(s.contains("rgb.txt:3") && s.contains("2 columns"), "{s}");
        let s = e(parse_list("1.0 a.png\nabc b.png\n", Path::new("rgb.txt")));
        assert!(s.contains("rgb.txt:2") && s.contains("timestamp"), "{s}");
        let s = e(parse_list("2.0 a.png\n1.0 b.png\n", Path::new("depth.txt")));
        assert!(s.contains("depth.txt:2") && s.contains("sorted"), "{s}");
        let s = e(read_list("/no/such/rgb.txt"));
        assert!(s.contains("/no/such/rgb.txt"), "{s}");
        // A repeated timestamp would drop a frame: an error naming both lines.
        let s = e(parse_list("1.0 a.png\n1.0 b.png\n", Path::new("rgb.txt")));
        assert!(
            s.contains("rgb.txt:2") && s.contains("repeats line 1"),
            "{s}"
        );

        let e = |t: &str| {
            parse_associations(t, Path::new("assoc.txt"))
                .unwrap_err()
                .to_string()
        };
        let s = e("1 rgb/1.png 1 depth/1.png\n2 rgb/2.png 2\n");
        assert!(s.contains("assoc.txt:2") && s.contains("4 columns"), "{s}");
        let s = e("1 rgb/1.png x depth/1.png\n");
        assert!(
            s.contains("assoc.txt:1") && s.contains("depth timestamp"),
            "{s}"
        );
        let s = e("1 rgb/1.png 1 depth/1.png\n1 rgb/1.png 1 depth/1.png\n");
        assert!(s.contains("assoc.txt:2") && s.contains("increasing"), "{s}");
    }

    #[test]
    fn real_fr1_xyz_lists_associate_like_the_literal_algorithm() {
        let Some(d) = data_dir() else { return };
        let seq = d.join("tum/rgbd_dataset_freiburg1_xyz");
        let rgb = read_list(seq.join("rgb.txt")).unwrap();
        let depth = read_list(seq.join("depth.txt")).unwrap();
        assert_eq!((rgb.len(), depth.len()), (300, 300));
        let a: Vec<f64> = rgb.iter().map(|e| e.t).collect();
        let b: Vec<f64> = depth.iter().map(|e| e.t).collect();
        let m = associate(&a, &b, 0.0, DEFAULT_MAX_DIFF);
        assert_eq!(m, associate_reference(&a, &b, 0.0, DEFAULT_MAX_DIFF));
        // Every match is within 20 ms and both sides are used at most once.
        assert!(m.iter().all(|&(i, j)| (a[i] - b[j]).abs() < 0.02));
        // Counts computed independently with the Python `associate.py` on the same files.
        assert_eq!(m.len(), 294);
        assert_eq!(
            format!("{:.6} {:.6}", a[m[0].0], b[m[0].1]),
            "1305031102.175304 1305031102.160407"
        );
        let full_rgb = read_list(seq.join("rgb_full_sequence.txt")).unwrap();
        let full_depth = read_list(seq.join("depth_full_sequence.txt")).unwrap();
        assert_eq!((full_rgb.len(), full_depth.len()), (798, 798));
        assert_eq!(
            associate_lists(&full_rgb, &full_depth, 0.0, DEFAULT_MAX_DIFF).len(),
            792
        );
    }

    #[test]
    fn real_walking_xyz_associations() {
        let Some(d) = data_dir() else { return };
        let p = d.join("tum-walking-meta/rgbd_dataset_freiburg3_walking_xyz/associations.txt");
        let a = read_associations(&p).unwrap();
        // The spec (§5.1) lists 827 frames for walking_xyz.
        assert_eq!(a.len(), 827);
        assert_eq!(a[0].rgb, "rgb/1341846313.592026.png");
        assert_eq!(format!("{:.6}", a[0].t_depth), "1341846313.592088");
        // Re-associating its own two columns reproduces the file (associate.py output).
        let rgb: Vec<ListEntry> = a
            .iter()
            .map(|x| ListEntry {
                t: x.t_rgb,
                path: x.rgb.clone(),
            })
            .collect();
        let depth: Vec<ListEntry> = a
            .iter()
            .map(|x| ListEntry {
                t: x.t_depth,
                path: x.depth.clone(),
            })
            .collect();
        assert_eq!(associate_lists(&rgb, &depth, 0.0, DEFAULT_MAX_DIFF), a);
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(
            associations_to_string(&a).trim_end(),
            text.trim_end().replace("\r", "")
        );
    }
}
