//! Multi-run and multi-sequence aggregation (spec §4.4): every configuration runs several
//! times; per method and sequence the mean and standard deviation over runs of ATE RMSE and
//! TR are reported; the "Average" row is the arithmetic mean over sequences of the
//! per-sequence means, and ATR = Average ATE / Average TR (from the Average row, not per
//! sequence). Rendered as Markdown, CSV and JSON.
//!
//! Every method also carries the motionless floor of its runs (the ATE of a camera that never
//! moves, on each run's pairs; [`crate::ate::motionless_floor`]) and the table one floor per
//! sequence (the mean over all its runs), so that a score is always seen next to what
//! standing still would give.
//!
//! Standard deviations are population values (numpy `std`, ddof 0). A run whose ATE cannot
//! be computed (e.g. no matching stamps) is listed with its error and left out of the ATE
//! statistics; its tracking rate still counts when available.

use crate::stats::mean_std;
use serde::Serialize;
use std::fmt::Write as _;

/// One run of one method on one sequence.
#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    /// Run name (trajectory file name).
    pub name: String,
    /// ATE RMSE, metres (`None` if it could not be computed).
    pub ate_rmse_m: Option<f64>,
    /// Matched pairs.
    pub pairs: usize,
    /// Tracking rate in [0, 1], when a reference was given.
    pub tracking_rate: Option<f64>,
    /// Missing time, seconds.
    pub missing_time_s: Option<f64>,
    /// Why the evaluation failed, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// Mean and standard deviation over runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MeanStd {
    /// Arithmetic mean.
    pub mean: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Number of values.
    pub n: usize,
}

impl MeanStd {
    /// `None` for an empty slice.
    pub fn of(values: &[f64]) -> Option<Self> {
        mean_std(values).map(|(mean, std)| Self {
            mean,
            std,
            n: values.len(),
        })
    }
}

/// All runs of one method on one sequence, summarised.
#[derive(Debug, Clone, Serialize)]
pub struct MethodSummary {
    /// Method name (folder name).
    pub method: String,
    /// ATE RMSE over successful runs, metres.
    pub ate: Option<MeanStd>,
    /// Tracking rate over runs with a tracking rate.
    pub tracking_rate: Option<MeanStd>,
    /// Runs that could not be evaluated.
    pub failed_runs: usize,
    /// The individual runs.
    pub runs: Vec<RunResult>,
    /// Motionless floor over the runs whose floor is known, metres.
    pub motionless_floor: Option<MeanStd>,
    /// Motionless floor of each run (parallel to `runs`; `None` when unknown or failed).
    pub run_floors_m: Vec<Option<f64>>,
}

/// Summarises the runs of one method with the motionless floor of each run (`floors`
/// parallel to `runs`; missing entries count as unknown).
pub fn summarize_with_floors(
    method: &str,
    runs: Vec<RunResult>,
    mut floors: Vec<Option<f64>>,
) -> MethodSummary {
    floors.resize(runs.len(), None);
    let ates: Vec<f64> = runs.iter().filter_map(|r| r.ate_rmse_m).collect();
    let trs: Vec<f64> = runs.iter().filter_map(|r| r.tracking_rate).collect();
    let known: Vec<f64> = floors.iter().flatten().copied().collect();
    MethodSummary {
        method: method.to_string(),
        ate: MeanStd::of(&ates),
        tracking_rate: MeanStd::of(&trs),
        failed_runs: runs.iter().filter(|r| r.error.is_some()).count(),
        runs,
        motionless_floor: MeanStd::of(&known),
        run_floors_m: floors,
    }
}

/// All methods on one sequence.
#[derive(Debug, Clone, Serialize)]
pub struct SequenceSummary {
    /// Sequence name.
    pub sequence: String,
    /// One summary per method.
    pub methods: Vec<MethodSummary>,
}

/// Per-method figures of the Average and ATR rows.
#[derive(Debug, Clone, Serialize)]
pub struct MethodAverage {
    /// Method name.
    pub method: String,
    /// Mean over sequences of the per-sequence ATE means (`None` if a sequence lacks one).
    pub ate_m: Option<f64>,
    /// Mean over sequences of the per-sequence TR means (`None` if a sequence lacks one).
    pub tracking_rate: Option<f64>,
    /// Average ATE / Average TR.
    pub atr: Option<f64>,
}

/// A paper-style table: sequences × methods, plus Average and ATR rows.
#[derive(Debug, Clone, Serialize)]
pub struct PaperTable {
    /// Methods in column order.
    pub methods: Vec<String>,
    /// Per-sequence summaries in row order.
    pub sequences: Vec<SequenceSummary>,
    /// Average and ATR per method, in column order.
    pub average: Vec<MethodAverage>,
    /// Motionless floor per sequence (parallel to `sequences`): the mean over all runs of
    /// all methods whose floor is known, metres.
    pub floors_m: Vec<Option<f64>>,
    /// Mean of the per-sequence floors (`None` if a sequence lacks one), metres.
    pub average_floor_m: Option<f64>,
}

/// The floor of one sequence: the mean over its runs' floors.
fn sequence_floor(s: &SequenceSummary) -> Option<f64> {
    let v: Vec<f64> = s
        .methods
        .iter()
        .flat_map(|m| m.run_floors_m.iter().flatten().copied())
        .collect();
    mean_std(&v).map(|(m, _)| m)
}

fn find<'a>(s: &'a SequenceSummary, method: &str) -> Option<&'a MethodSummary> {
    s.methods.iter().find(|m| m.method == method)
}

/// Builds the table. Methods are the union over sequences, in order of first appearance.
pub fn paper_table(sequences: Vec<SequenceSummary>) -> PaperTable {
    let mut methods: Vec<String> = Vec::new();
    for s in &sequences {
        for m in &s.methods {
            if !methods.contains(&m.method) {
                methods.push(m.method.clone());
            }
        }
    }
    let average = methods
        .iter()
        .map(|name| {
            let mean_of = |f: &dyn Fn(&MethodSummary) -> Option<MeanStd>| -> Option<f64> {
                let v: Option<Vec<f64>> = sequences
                    .iter()
                    .map(|s| find(s, name).and_then(f).map(|x| x.mean))
                    .collect();
                v.and_then(|v| mean_std(&v)).map(|(m, _)| m)
            };
            let ate = mean_of(&|m| m.ate);
            let tr = mean_of(&|m| m.tracking_rate);
            let atr = match (ate, tr) {
                (Some(a), Some(t)) if t > 0.0 => Some(a / t),
                _ => None,
            };
            MethodAverage {
                method: name.clone(),
                ate_m: ate,
                tracking_rate: tr,
                atr,
            }
        })
        .collect();
    let floors_m: Vec<Option<f64>> = sequences.iter().map(sequence_floor).collect();
    let average_floor_m = floors_m
        .iter()
        .copied()
        .collect::<Option<Vec<f64>>>()
        .and_then(|v| mean_std(&v))
        .map(|(m, _)| m);
    PaperTable {
        methods,
        sequences,
        average,
        floors_m,
        average_floor_m,
    }
}

fn cell(v: Option<MeanStd>, digits: usize) -> String {
    match v {
        Some(m) => format!("{:.*} ± {:.*}", digits, m.mean, digits, m.std),
        None => "—".to_string(),
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "—".to_string(), |x| format!("{x:.digits$}"))
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

impl PaperTable {
    /// True when any method on any sequence has a tracking rate.
    pub fn has_tracking(&self) -> bool {
        self.sequences
            .iter()
            .any(|s| s.methods.iter().any(|m| m.tracking_rate.is_some()))
    }

    /// True when any sequence has a motionless floor.
    pub fn has_floor(&self) -> bool {
        self.floors_m.iter().any(Option::is_some)
    }

    /// Markdown table: one row per sequence, a `motionless floor [m]` column when floors are
    /// known, per method an `ATE [m]` column (and `TR` when known), then the Average and ATR
    /// rows.
    pub fn to_markdown(&self) -> String {
        let tr = self.has_tracking();
        let floor = self.has_floor();
        let mut out = String::from("| Sequence |");
        let mut sep = String::from("|---|");
        if floor {
            out.push_str(" motionless floor [m] |");
            sep.push_str("---:|");
        }
        for m in &self.methods {
            let _ = write!(out, " {m} ATE [m] |");
            sep.push_str("---:|");
            if tr {
                let _ = write!(out, " {m} TR |");
                sep.push_str("---:|");
            }
        }
        out.push('\n');
        out.push_str(&sep);
        out.push('\n');
        for (k, s) in self.sequences.iter().enumerate() {
            let _ = write!(out, "| {} |", s.sequence);
            if floor {
                let f = self.floors_m.get(k).copied().flatten();
                let _ = write!(out, " {} |", opt(f, 3));
            }
            for m in &self.methods {
                let ms = find(s, m);
                let _ = write!(out, " {} |", cell(ms.and_then(|x| x.ate), 3));
                if tr {
                    let _ = write!(out, " {} |", cell(ms.and_then(|x| x.tracking_rate), 2));
                }
            }
            out.push('\n');
        }
        out.push_str("| **Average** |");
        if floor {
            let _ = write!(out, " {} |", opt(self.average_floor_m, 3));
        }
        for a in &self.average {
            let _ = write!(out, " {} |", opt(a.ate_m, 3));
            if tr {
                let _ = write!(out, " {} |", opt(a.tracking_rate, 2));
            }
        }
        out.push('\n');
        if tr {
            out.push_str("| **ATR** |");
            if floor {
                out.push_str(" |");
            }
            for a in &self.average {
                let _ = write!(out, " {} | |", opt(a.atr, 3));
            }
            out.push('\n');
        }
        out
    }

    /// CSV in long form: `sequence,method,ate_mean_m,ate_std_m,tr_mean,tr_std,runs,failed_runs,
    /// motionless_floor_m` (the method's mean floor over its runs), then rows with sequence
    /// `Average` and `ATR` (ATR in the `ate_mean_m` column; the Average rows carry the mean of
    /// the per-sequence floors).
    pub fn to_csv(&self) -> String {
        let mut out = String::from(
            "sequence,method,ate_mean_m,ate_std_m,tr_mean,tr_std,runs,failed_runs,motionless_floor_m\n",
        );
        let num = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:.6}"));
        for s in &self.sequences {
            for m in &s.methods {
                let _ = writeln!(
                    out,
                    "{},{},{},{},{},{},{},{},{}",
                    csv_field(&s.sequence),
                    csv_field(&m.method),
                    num(m.ate.map(|x| x.mean)),
                    num(m.ate.map(|x| x.std)),
                    num(m.tracking_rate.map(|x| x.mean)),
                    num(m.tracking_rate.map(|x| x.std)),
                    m.runs.len(),
                    m.failed_runs,
                    num(m.motionless_floor.map(|x| x.mean))
                );
            }
        }
        for a in &self.average {
            let _ = writeln!(
                out,
                "Average,{},{},,{},,,,{}",
                csv_field(&a.method),
                num(a.ate_m),
                num(a.tracking_rate),
                num(self.average_floor_m)
            );
        }
        for a in &self.average {
            let _ = writeln!(out, "ATR,{},{},,,,,,", csv_field(&a.method), num(a.atr));
        }
        out
    }

    /// Pretty-printed JSON of the whole table (runs included).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(ate: f64, tr: f64) -> RunResult {
        RunResult {
            name: "r".into(),
            ate_rmse_m: Some(ate),
            pairs: 10,
            tracking_rate: Some(tr),
            missing_time_s: Some(0.0),
            error: None,
        }
    }

    #[test]
    fn average_and_atr_follow_the_paper_definition() {
        let s1 = SequenceSummary {
            sequence: "a".into(),
            methods: vec![summarize_with_floors(
                "M",
                vec![run(0.01, 1.0), run(0.03, 0.8)],
                vec![],
            )],
        };
        let s2 = SequenceSummary {
            sequence: "b".into(),
            methods: vec![summarize_with_floors("M", vec![run(0.06, 0.5)], vec![])],
        };
        let t = paper_table(vec![s1, s2]);
        let m = &t.sequences[0].methods[0];
        let ate = m.ate.expect("ate");
        assert!((ate.mean - 0.02).abs() < 1e-15 && (ate.std - 0.01).abs() < 1e-15);
        let a = &t.average[0];
        // Average ATE = (0.02 + 0.06)/2, Average TR = (0.9 + 0.5)/2, ATR = 0.04/0.7.
        assert!((a.ate_m.expect("avg") - 0.04).abs() < 1e-15);
        assert!((a.tracking_rate.expect("avg") - 0.7).abs() < 1e-15);
        assert!((a.atr.expect("atr") - 0.04 / 0.7).abs() < 1e-15);
        let md = t.to_markdown();
        assert!(md.contains("| a | 0.020 ± 0.010 | 0.90 ± 0.10 |"), "{md}");
        assert!(md.contains("| **ATR** | 0.057 |"), "{md}");
        let csv = t.to_csv();
        assert!(
            csv.contains("a,M,0.020000,0.010000,0.900000,0.100000,2,0"),
            "{csv}"
        );
        assert!(csv.contains("ATR,M,0.057143"), "{csv}");
        let json: serde_json::Value = serde_json::from_str(&t.to_json()).expect("json");
        assert_eq!(json["average"][0]["method"], "M");
        // Without floors the table has no floor column.
        assert!(!t.has_floor() && !md.contains("floor"), "{md}");
    }

    #[test]
    fn floors_per_run_method_and_sequence() {
        let s1 = SequenceSummary {
            sequence: "a".into(),
            methods: vec![
                summarize_with_floors(
                    "M",
                    vec![run(0.01, 1.0), run(0.03, 1.0)],
                    vec![Some(0.07), Some(0.09)],
                ),
                summarize_with_floors("N", vec![run(0.2, 1.0)], vec![Some(0.08)]),
            ],
        };
        let s2 = SequenceSummary {
            sequence: "b".into(),
            methods: vec![summarize_with_floors(
                "M",
                vec![run(0.002, 1.0)],
                vec![Some(0.004)],
            )],
        };
        let m = &s1.methods[0];
        let f = m.motionless_floor.expect("floor");
        assert!((f.mean - 0.08).abs() < 1e-15 && (f.std - 0.01).abs() < 1e-15 && f.n == 2);
        let t = paper_table(vec![s1, s2]);
        // Sequence a: mean of 0.07, 0.09, 0.08; b: 0.004; Average: 0.042.
        assert!((t.floors_m[0].expect("a") - 0.08).abs() < 1e-15);
        assert!((t.floors_m[1].expect("b") - 0.004).abs() < 1e-15);
        assert!((t.average_floor_m.expect("avg") - 0.042).abs() < 1e-15);
        let md = t.to_markdown();
        assert!(
            md.starts_with("| Sequence | motionless floor [m] | M ATE [m] |"),
            "{md}"
        );
        assert!(md.contains("| a | 0.080 | 0.020 ± 0.010 |"), "{md}");
        assert!(md.contains("| **Average** | 0.042 |"), "{md}");
        let csv = t.to_csv();
        assert!(
            csv.contains("a,M,0.020000,0.010000,1.000000,0.000000,2,0,0.080000"),
            "{csv}"
        );
        assert!(
            csv.contains("Average,M,0.011000,,1.000000,,,,0.042000"),
            "{csv}"
        );
        let json: serde_json::Value = serde_json::from_str(&t.to_json()).expect("json");
        assert_eq!(json["floors_m"][1], 0.004);
        assert_eq!(json["sequences"][0]["methods"][0]["run_floors_m"][1], 0.09);
        // A missing floor is unknown, not zero; an empty floor list has none.
        let m = summarize_with_floors("M", vec![run(0.01, 1.0), run(0.02, 1.0)], vec![Some(0.1)]);
        assert_eq!(m.run_floors_m, vec![Some(0.1), None]);
        assert_eq!(m.motionless_floor.map(|x| x.n), Some(1));
        assert!(
            summarize_with_floors("M", vec![run(0.01, 1.0)], vec![])
                .motionless_floor
                .is_none()
        );
    }

    #[test]
    fn failed_runs_are_counted_but_not_averaged() {
        let mut bad = run(0.0, 0.2);
        bad.ate_rmse_m = None;
        bad.error = Some("no pairs".into());
        let m = summarize_with_floors("M", vec![run(0.05, 1.0), bad], vec![]);
        assert_eq!(m.failed_runs, 1);
        assert_eq!(m.ate.map(|a| a.n), Some(1));
        assert_eq!(m.tracking_rate.map(|a| a.n), Some(2));
    }
}
