//! `binpick replay`: recognition over recorded scans without ground truth, made for tuning:
//! a per-scan table on stdout, a CSV with per-stage timings, pictures, a comparison of two
//! configurations on the same scans, and shards for splitting an archive across machines.
//!
//! Output folder (`--out`, default `replay-out/`):
//!
//! ```text
//! scans/<name>.json      one result per scan (schema/result.schema.json)
//! compare/<name>.json    with --compare: the other configuration's results
//! replay.csv             one row per scan and configuration (columns: CSV_COLUMNS)
//! compare.csv            with --compare: per-scan differences
//! summary.json           totals, per-scan records, the parameters; summary.params.toml
//! ```
//!
//! With `--shard i/n` the tables are `replay-iofn.csv`, `compare-iofn.csv` and
//! `summary-iofn.json`, so every shard can write into the same folder.
//!
//! `<name>` is the scan's file stem plus 8 hex digits of a hash of its path as given, so two
//! scans with the same file name never share an output; the names do not depend on
//! `--shard`, so shards write disjoint files into one folder.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use binpick::{Params, RecognitionReport, Recognizer};
use binpick_eval::{ReplayResult, median_p95, replay_scan};
use serde::Serialize;

use crate::Done;
use crate::config::{
    BopArgs, FrameArgs, ParamArgs, load_part, write_json, write_params_next_to, write_text,
};
use crate::progress::Progress;

#[derive(clap::Args)]
pub struct Args {
    /// Scan files (.pcd or .ply). They are sorted and de-duplicated first, so every machine
    /// of a sharded run sees the same order.
    #[arg(required = true)]
    pub scans: Vec<PathBuf>,
    /// Part model: scanned cloud or CAD mesh (as `recognize --model`).
    #[arg(long)]
    pub model: PathBuf,
    #[command(flatten)]
    pub params: ParamArgs,
    /// Output folder: scans/<name>.json, replay.csv, summary.json (see README "Replay").
    #[arg(long, default_value = "replay-out")]
    pub out: PathBuf,
    /// Render each result as <DIR>/<name>.png (scanner view and oblique view).
    #[arg(long, value_name = "DIR")]
    pub png: Option<PathBuf>,
    /// Run a second configuration on the same scans: the same preset and flags with this TOML
    /// file in place of --config. Prints the per-scan and total differences and writes
    /// compare.csv.
    #[arg(long, value_name = "other.toml")]
    pub compare: Option<PathBuf>,
    /// Process only shard i of n (1 <= i <= n): every n-th scan of the sorted list, starting
    /// at the i-th. For GNU parallel or a SLURM array (README "Replay").
    #[arg(long, value_name = "i/n")]
    pub shard: Option<Shard>,
    #[command(flatten)]
    pub bop: BopArgs,
    #[command(flatten)]
    pub frame: FrameArgs,
}

/// One shard of a scan list.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 1-based.
    pub index: usize,
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: expected i/n with 1 <= i <= n, e.g. 2/8");
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index == 0 || index > count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

impl Shard {
    /// Whether the `k`-th (0-based) item of the full list belongs to this shard.
    pub fn takes(&self, k: usize) -> bool {
        k % self.count == self.index - 1
    }
}

/// FNV-1a, 64 bit: a hash that is the same on every machine and Rust version.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Output names for `scans` (sorted, distinct): `<stem>-<8 hex digits of the path's hash>`,
/// with `-2`, `-3`, ... appended in the (astronomically unlikely) case two still collide.
pub fn output_names(scans: &[PathBuf]) -> Vec<String> {
    let mut used = HashSet::new();
    scans
        .iter()
        .map(|p| {
            let stem = p
                .file_stem()
                .map_or_else(|| "scan".to_owned(), |s| s.to_string_lossy().into_owned());
            let hash = fnv1a(p.to_string_lossy().as_bytes()) >> 32;
            let base = format!("{stem}-{hash:08x}");
            let mut name = base.clone();
            let mut k = 1;
            while !used.insert(name.clone()) {
                k += 1;
                name = format!("{base}-{k}");
            }
            name
        })
        .collect()
}

/// Columns of `replay.csv`.
pub const CSV_COLUMNS: &str = "config,scan,name,detections,pick_x_mm,pick_y_mm,pick_z_mm,pick_roll_deg,pick_pitch_deg,pick_yaw_deg,pick_visibility_pct,pick_final_score_pct,pick_initial_score_mm2,visibilities_pct,final_scores_pct,total_ms,preprocess_ms,clustering_ms,initial_alignment_ms,final_alignment_ms,ranking_ms,model_preparation_ms,error";

#[derive(Serialize)]
struct Summary<'a> {
    model: String,
    units: &'static str,
    shard: Option<String>,
    scans: usize,
    failed: usize,
    detections_total: usize,
    scans_without_detection: usize,
    /// Scans with detections but none free to pick: no first pick.
    scans_none_free_to_pick: usize,
    /// Scans whose time budget ran out (their JSON holds what was verified before it).
    budget_exhausted: usize,
    time_ms_median: f64,
    time_ms_p95: f64,
    results: &'a [ReplayResult],
    params: &'a Params,
    #[serde(skip_serializing_if = "Option::is_none")]
    compare: Option<CompareSummary<'a>>,
}

#[derive(Serialize)]
struct CompareSummary<'a> {
    config: String,
    detections_total: usize,
    scans_without_detection: usize,
    scans_none_free_to_pick: usize,
    failed: usize,
    budget_exhausted: usize,
    time_ms_median: f64,
    first_pick_changed: usize,
    results: &'a [ReplayResult],
    params: &'a Params,
}

/// A first pick that moved more than this, mm, counts as changed.
const PICK_MOVED_MM: f64 = 1.0;

pub fn run(a: Args) -> Result<Done> {
    let params = a.params.params()?;
    let frame = a.frame.frame()?;
    let other = match &a.compare {
        Some(toml) => {
            let mut args = a.params.clone();
            args.config = Some(toml.clone());
            Some(args.params().context("--compare")?)
        }
        None => None,
    };
    let mut all: Vec<PathBuf> = a.scans.clone();
    all.sort();
    all.dedup();
    let names = output_names(&all);
    let selected: Vec<(usize, &PathBuf, &String)> = all
        .iter()
        .zip(&names)
        .enumerate()
        .filter(|(k, _)| a.shard.is_none_or(|s| s.takes(*k)))
        .map(|(k, (p, n))| (k, p, n))
        .collect();
    if let Some(s) = a.shard {
        tracing::info!(
            "shard {}/{}: {} of {} scan(s)",
            s.index,
            s.count,
            selected.len(),
            all.len()
        );
    }
    let part = load_part(&a.model, a.params.model_units(&params), &params)?;
    let recognizer =
        Recognizer::with_part(part.clone(), params.clone()).context("cannot prepare the model")?;
    let other_recognizer = match &other {
        Some(p) => Some(
            Recognizer::with_part(part.clone(), p.clone())
                .context("cannot prepare the model for --compare")?,
        ),
        None => None,
    };
    let scans_dir = a.out.join("scans");
    std::fs::create_dir_all(&scans_dir)
        .with_context(|| format!("cannot create {}", scans_dir.display()))?;
    let model_name = a.model.display().to_string();
    let progress = Progress::new(selected.len(), "replay");
    let mut results = Vec::new();
    let mut other_results = Vec::new();
    let mut bop_rows = String::from(binpick_eval::bop::CSV_HEADER);
    for (done, &(k, scan, name)) in selected.iter().enumerate() {
        let mut r = replay_scan(&recognizer, scan, &model_name, params.units);
        if let Some(report) = &mut r.report {
            // Pictures and BOP rows in the scanner's frame, everything else in the output
            // frame.
            if let Some(dir) = &a.png {
                write_png(
                    report,
                    scan,
                    &part,
                    params.units,
                    &dir.join(format!("{name}.png")),
                )?;
            }
            bop_rows.push_str(&binpick_eval::bop::csv_rows(
                a.bop.ids_for(scan, k),
                &report.detections,
                report.timings_ms.total_ms / 1000.0,
            ));
            if let Some(f) = &frame {
                report.express_in(f);
            }
            write_json(&scans_dir.join(format!("{name}.json")), report)?;
        }
        let mut msg = outcome(&r);
        if let (Some(rec), Some(p)) = (&other_recognizer, &other) {
            let mut o = replay_scan(rec, scan, &model_name, p.units);
            if let Some(report) = &mut o.report {
                if let Some(f) = &frame {
                    report.express_in(f);
                }
                write_json(&a.out.join("compare").join(format!("{name}.json")), report)?;
            }
            msg = format!("{msg} | compare: {}", outcome(&o));
            other_results.push(o);
        }
        progress.step(done + 1, &format!("{}: {msg}", scan.display()));
        results.push(r);
    }
    progress.finish();

    let rows: Vec<(&str, &String, &ReplayResult)> = results
        .iter()
        .zip(&selected)
        .map(|(r, (_, _, n))| ("base", *n, r))
        .chain(
            other_results
                .iter()
                .zip(&selected)
                .map(|(r, (_, _, n))| ("compare", *n, r)),
        )
        .collect();
    // Shards write their own tables, so all shards can share one output folder.
    let suffix = a
        .shard
        .map_or(String::new(), |s| format!("-{}of{}", s.index, s.count));
    write_text(
        &a.out.join(format!("replay{suffix}.csv")),
        &replay_csv(&rows),
    )?;
    if let Some(path) = &a.bop.bop_csv {
        write_text(path, &bop_rows)?;
        tracing::info!("wrote {} (BOP results)", path.display());
    }

    let names_sel: Vec<&String> = selected.iter().map(|(_, _, n)| *n).collect();
    let mut stdout = std::io::stdout().lock();
    let totals = Totals::of(&results);
    let compare = if let Some(p) = &other {
        let other_totals = Totals::of(&other_results);
        let diffs = print_compare(&mut stdout, &names_sel, &results, &other_results)?;
        let changed = diffs.iter().filter(|d| d.pick_changed).count();
        print_compare_totals(&mut stdout, &totals, &other_totals, changed, diffs.len())?;
        write_text(
            &a.out.join(format!("compare{suffix}.csv")),
            &compare_csv(&names_sel, &diffs),
        )?;
        Some(CompareSummary {
            config: a
                .compare
                .as_ref()
                .map(|c| c.display().to_string())
                .unwrap_or_default(),
            detections_total: other_totals.detections,
            scans_without_detection: other_totals.without,
            scans_none_free_to_pick: other_totals.none_free,
            failed: other_totals.failed,
            budget_exhausted: other_totals.budget_exhausted,
            time_ms_median: other_totals.median_ms,
            first_pick_changed: changed,
            results: &other_results,
            params: p,
        })
    } else {
        print_table(&mut stdout, &names_sel, &results)?;
        print_totals(&mut stdout, &totals)?;
        None
    };
    let summary = Summary {
        model: model_name,
        units: "mm",
        shard: a.shard.map(|s| format!("{}/{}", s.index, s.count)),
        scans: results.len(),
        failed: totals.failed,
        detections_total: totals.detections,
        scans_without_detection: totals.without,
        scans_none_free_to_pick: totals.none_free,
        budget_exhausted: totals.budget_exhausted,
        time_ms_median: totals.median_ms,
        time_ms_p95: totals.p95_ms,
        results: &results,
        params: &params,
        compare,
    };
    let summary_path = a.out.join(format!("summary{suffix}.json"));
    write_json(&summary_path, &summary)?;
    write_params_next_to(&summary_path, &params)?;
    tracing::info!(
        "wrote {}: scans/*.json, replay{suffix}.csv{}, summary{suffix}.json",
        a.out.display(),
        if other.is_some() {
            format!(", compare/*.json, compare{suffix}.csv")
        } else {
            String::new()
        }
    );
    for r in results
        .iter()
        .chain(&other_results)
        .filter(|r| r.error.is_some())
    {
        tracing::warn!("{}: {}", r.scan.display(), r.error.as_deref().unwrap_or(""));
    }
    let failed = totals.failed + other_results.iter().filter(|r| r.error.is_some()).count();
    if failed > 0 {
        bail!("{failed} scan run(s) failed");
    }
    let other_exhausted = other_results.iter().filter(|r| interrupted(r)).count();
    Ok(if summary.budget_exhausted + other_exhausted > 0 {
        Done::BudgetExhausted
    } else {
        Done::Complete
    })
}

/// Whether the scan's time budget ran out (or its call was otherwise stopped early).
fn interrupted(r: &binpick_eval::ReplayResult) -> bool {
    r.report
        .as_ref()
        .is_some_and(|rep| rep.interrupted.is_some())
}

fn outcome(r: &ReplayResult) -> String {
    match &r.error {
        Some(e) => format!("ERROR {e}"),
        None => format!(
            "{} found, {:.0} ms{}",
            r.detections,
            r.time_ms,
            if interrupted(r) {
                " (time budget ran out: incomplete)"
            } else {
                ""
            }
        ),
    }
}

fn write_png(
    report: &RecognitionReport,
    scan: &Path,
    part: &binpick::Part,
    units: binpick::Units,
    path: &Path,
) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let (scene, _) = binpick::load_cloud(scan, units).context("cannot reload the scan")?;
    crate::recognize::write_pictures(report, &scene, &part.cloud, Some(path), None)
}

/// Totals of one configuration's results.
struct Totals {
    scans: usize,
    failed: usize,
    detections: usize,
    without: usize,
    /// Scans with detections but none free to pick.
    none_free: usize,
    /// Scans whose time budget ran out (their JSON holds what was verified before it).
    budget_exhausted: usize,
    median_ms: f64,
    p95_ms: f64,
}

impl Totals {
    fn of(results: &[ReplayResult]) -> Self {
        let ok: Vec<&ReplayResult> = results.iter().filter(|r| r.error.is_none()).collect();
        let times: Vec<f64> = ok.iter().map(|r| r.time_ms).collect();
        let (median_ms, p95_ms) = median_p95(&times);
        Self {
            scans: results.len(),
            failed: results.len() - ok.len(),
            detections: ok.iter().map(|r| r.detections).sum(),
            without: ok.iter().filter(|r| r.detections == 0).count(),
            none_free: ok
                .iter()
                .filter(|r| r.report.as_ref().is_some_and(|rep| rep.none_free_to_pick()))
                .count(),
            budget_exhausted: ok.iter().filter(|r| interrupted(r)).count(),
            median_ms,
            p95_ms,
        }
    }
}

/// The first pick's position, mm.
fn pick(r: &ReplayResult) -> Option<nalgebra::Vector3<f64>> {
    r.report
        .as_ref()?
        .first_pick()
        .map(|d| d.pose.translation.vector)
}

fn print_table(
    out: &mut impl std::io::Write,
    names: &[&String],
    results: &[ReplayResult],
) -> std::io::Result<()> {
    writeln!(
        out,
        "{:<36} {:>5}  {:>9} {:>9} {:>9}  {:>6} {:>8}  {:>8}",
        "scan", "found", "pick x mm", "y mm", "z mm", "vis %", "final %", "ms"
    )?;
    for (name, r) in names.iter().zip(results) {
        if let Some(e) = &r.error {
            writeln!(out, "{name:<36} ERROR {e}")?;
            continue;
        }
        let first = r.report.as_ref().and_then(|rep| rep.first_pick());
        let (pos, vis, fin) = match first {
            Some(d) => {
                let t = d.pose.translation.vector;
                (
                    format!("{:>9.2} {:>9.2} {:>9.2}", t.x, t.y, t.z),
                    d.view
                        .map_or("-".into(), |v| format!("{:.1}", 100.0 * v.visibility)),
                    format!("{:.2}", d.final_score),
                )
            }
            None => (
                format!("{:>9} {:>9} {:>9}", "-", "-", "-"),
                "-".into(),
                "-".into(),
            ),
        };
        writeln!(
            out,
            "{name:<36} {:>5}  {pos}  {vis:>6} {fin:>8}  {:>8.0}",
            r.detections, r.time_ms
        )?;
    }
    Ok(())
}

fn print_totals(out: &mut impl std::io::Write, t: &Totals) -> std::io::Result<()> {
    writeln!(
        out,
        "{} scan(s): {} detection(s), {} without any, {} with none free to pick (no pick), {} failed, {} out of time budget; time per scan median {:.0} ms, p95 {:.0} ms",
        t.scans,
        t.detections,
        t.without,
        t.none_free,
        t.failed,
        t.budget_exhausted,
        t.median_ms,
        t.p95_ms
    )
}

/// One scan's difference between the two configurations.
struct Diff {
    found: (usize, usize),
    /// Distance between the two first picks, mm (None when either has none).
    pick_moved_mm: Option<f64>,
    pick_changed: bool,
    ms: (f64, f64),
    failed: bool,
}

fn print_compare(
    out: &mut impl std::io::Write,
    names: &[&String],
    base: &[ReplayResult],
    other: &[ReplayResult],
) -> std::io::Result<Vec<Diff>> {
    writeln!(
        out,
        "{:<36} {:>7} {:>7} {:>5}  {:>13}  {:>8} {:>8} {:>8}",
        "scan", "found", "compare", "diff", "pick moved mm", "ms", "compare", "diff"
    )?;
    let mut diffs = Vec::new();
    for ((name, a), b) in names.iter().zip(base).zip(other) {
        let moved = match (pick(a), pick(b)) {
            (Some(p), Some(q)) => Some((p - q).norm()),
            _ => None,
        };
        let changed = match (pick(a), pick(b)) {
            (Some(_), Some(_)) => moved.is_some_and(|m| m > PICK_MOVED_MM),
            (None, None) => false,
            _ => true,
        };
        let d = Diff {
            found: (a.detections, b.detections),
            pick_moved_mm: moved,
            pick_changed: changed,
            ms: (a.time_ms, b.time_ms),
            failed: a.error.is_some() || b.error.is_some(),
        };
        let moved_text = match (moved, changed) {
            (Some(m), _) => format!("{m:.2}"),
            (None, true) => "appeared/gone".into(),
            (None, false) => "-".into(),
        };
        writeln!(
            out,
            "{name:<36} {:>7} {:>7} {:>+5}  {moved_text:>13}  {:>8.0} {:>8.0} {:>+8.0}{}",
            d.found.0,
            d.found.1,
            d.found.1 as i64 - d.found.0 as i64,
            d.ms.0,
            d.ms.1,
            d.ms.1 - d.ms.0,
            if d.failed { "  (a run failed)" } else { "" }
        )?;
        diffs.push(d);
    }
    Ok(diffs)
}

fn print_compare_totals(
    out: &mut impl std::io::Write,
    a: &Totals,
    b: &Totals,
    changed: usize,
    scans: usize,
) -> std::io::Result<()> {
    writeln!(
        out,
        "total over {scans} scan(s): detections {} -> {} ({:+}), scans without detection {} -> {} ({:+}), with none free to pick {} -> {}, failed {} -> {}, out of time budget {} -> {}, median ms {:.0} -> {:.0} ({:+.0}); first pick changed on {changed} scan(s) (moved > {PICK_MOVED_MM} mm, appeared or gone)",
        a.detections,
        b.detections,
        b.detections as i64 - a.detections as i64,
        a.without,
        b.without,
        b.without as i64 - a.without as i64,
        a.none_free,
        b.none_free,
        a.failed,
        b.failed,
        a.budget_exhausted,
        b.budget_exhausted,
        a.median_ms,
        b.median_ms,
        b.median_ms - a.median_ms
    )
}

/// A CSV field, quoted when it needs to be.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

fn replay_csv(rows: &[(&str, &String, &ReplayResult)]) -> String {
    let columns = CSV_COLUMNS.split(',').count();
    let mut s = format!("{CSV_COLUMNS}\n");
    for (config, name, r) in rows {
        let mut f: Vec<String> = vec![
            (*config).to_owned(),
            field(&r.scan.display().to_string()),
            (*name).clone(),
            r.detections.to_string(),
        ];
        if let Some(report) = &r.report {
            match report.first_pick() {
                Some(d) => {
                    let t = d.pose.translation.vector;
                    let [ro, pi, ya] = crate::table::rpy_deg(&d.pose);
                    f.extend([
                        format!("{:.3}", t.x),
                        format!("{:.3}", t.y),
                        format!("{:.3}", t.z),
                        format!("{ro:.2}"),
                        format!("{pi:.2}"),
                        format!("{ya:.2}"),
                        d.view
                            .map_or(String::new(), |v| format!("{:.2}", 100.0 * v.visibility)),
                        format!("{:.3}", d.final_score),
                        format!("{:.4}", d.initial_score),
                    ]);
                }
                None => f.extend(std::iter::repeat_n(String::new(), 9)),
            }
            let vis: Vec<String> = report
                .detections
                .iter()
                .filter_map(|d| d.view.map(|v| format!("{:.2}", 100.0 * v.visibility)))
                .collect();
            let fin: Vec<String> = report
                .detections
                .iter()
                .map(|d| format!("{:.3}", d.final_score))
                .collect();
            let t = &report.timings_ms;
            f.push(vis.join(" "));
            f.push(fin.join(" "));
            f.extend(
                [
                    t.total_ms,
                    t.preprocess_ms,
                    t.clustering_ms,
                    t.initial_alignment_ms,
                    t.final_alignment_ms,
                    t.ranking_ms,
                    t.model_preparation_ms,
                ]
                .map(|v| format!("{v:.1}")),
            );
        }
        f.resize(columns - 1, String::new());
        f.push(field(r.error.as_deref().unwrap_or("")));
        s.push_str(&f.join(","));
        s.push('\n');
    }
    s
}

fn compare_csv(names: &[&String], diffs: &[Diff]) -> String {
    let mut s = String::from(
        "name,detections,detections_compare,detections_diff,first_pick_moved_mm,first_pick_changed,ms,ms_compare,ms_diff,failed\n",
    );
    for (n, d) in names.iter().zip(diffs) {
        s.push_str(&format!(
            "{n},{},{},{},{},{},{:.1},{:.1},{:.1},{}\n",
            d.found.0,
            d.found.1,
            d.found.1 as i64 - d.found.0 as i64,
            d.pick_moved_mm.map_or(String::new(), |m| format!("{m:.3}")),
            u8::from(d.pick_changed),
            d.ms.0,
            d.ms.1,
            d.ms.1 - d.ms.0,
            u8::from(d.failed)
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_a_list_into_disjoint_parts_that_cover_it() {
        let n = 3;
        let shards: Vec<Shard> = (1..=n)
            .map(|i| format!("{i}/{n}").parse().unwrap())
            .collect();
        for k in 0..10 {
            assert_eq!(shards.iter().filter(|s| s.takes(k)).count(), 1, "item {k}");
        }
        assert!(shards[0].takes(0) && shards[1].takes(1) && shards[0].takes(3));
        for bad in ["0/2", "3/2", "1/0", "1", "a/b", "1/2/3"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn same_file_names_in_different_folders_get_different_outputs() {
        let scans = vec![
            PathBuf::from("day1/scan.pcd"),
            PathBuf::from("day2/scan.pcd"),
            PathBuf::from("scan.pcd"),
        ];
        let names = output_names(&scans);
        assert_eq!(names.len(), 3);
        assert!(
            names
                .iter()
                .all(|n| n.starts_with("scan-") && n.len() == 13)
        );
        let distinct: HashSet<&String> = names.iter().collect();
        assert_eq!(distinct.len(), 3, "{names:?}");
        // Stable: the same path always gets the same name.
        assert_eq!(output_names(&scans[1..2])[0], names[1]);
        // FNV-1a's published test vector.
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }

    #[test]
    fn csv_fields_are_quoted_when_needed() {
        assert_eq!(field("a.pcd"), "a.pcd");
        assert_eq!(field("a,b.pcd"), "\"a,b.pcd\"");
        assert_eq!(field("say \"x\""), "\"say \"\"x\"\"\"");
    }
}
