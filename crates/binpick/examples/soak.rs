//! Soak run: many threads share one `Recognizer` and call it over and over with a mix of
//! good and broken scans. Every answer must equal the serial answer for the same input, and
//! resident memory must stay flat once warmed up.
//!
//! ```text
//! cargo run --release -p binpick --example soak -- [--callers 8] [--calls 125] [--threads 0]
//!     [--serial-rounds 3] [--sample-only]
//! ```
//!
//! Inputs (run from the repository root): part A of `data/sample` (model, preset A) against
//! the sample scan, the four `data/tiny` scans, the sample scan with a stray point at 1e30,
//! and broken inputs: a missing file, a truncated PCD, a file of garbage, an empty cloud, a
//! one-point cloud, a cloud in metres and a cloud with a NaN coordinate. `--sample-only`: the
//! sample scan alone (every call the same 0.6 s recognition, to measure latency under load).
//!
//! Phases: (1) serial: each input once to warm up and record its answer, then
//! `--serial-rounds` more rounds, timed (serial throughput); (2) concurrent: `--callers`
//! threads x `--calls` calls, thread t's call i taking input (t x calls + i) mod inputs.
//! Prints throughput (calls/s) of both, the latency (call to return, queue included) median
//! and maximum, the queue wait, and resident memory (/proc/self/statm) after warm-up (the
//! first 10 % of concurrent calls) and at the end. Exit code 1 if any answer differs from
//! the serial one or memory grew by 5 % or more after warm-up.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use binpick::{PointCloud, Preset, Recognition, Recognizer, Units, load_cloud};

/// One input of the mix.
enum Input {
    File(PathBuf),
    Cloud(String, PointCloud),
}

impl Input {
    fn name(&self) -> String {
        match self {
            Input::File(p) => p.display().to_string(),
            Input::Cloud(name, _) => name.clone(),
        }
    }
}

/// What a call returned, reduced to what must not change between runs: the detections,
/// cluster reports and preprocessing counts (bit for bit), or the error message.
#[derive(Clone, Debug, PartialEq)]
enum Answer {
    Found(
        Box<(
            Vec<binpick::Detection>,
            Vec<binpick::ClusterReport>,
            binpick::PreprocessReport,
        )>,
    ),
    Failed(String),
}

/// The answer and, for a recognition that ran, its queue wait (ms).
fn answer(r: binpick::Result<Recognition>) -> (Answer, Option<f64>) {
    match r {
        Ok(r) => (
            Answer::Found(Box::new((r.detections, r.clusters, r.preprocess))),
            Some(r.timings.queue_ms),
        ),
        Err(e) => (Answer::Failed(e.to_string()), None),
    }
}

fn call(rec: &Recognizer, input: &Input) -> (Answer, Option<f64>) {
    match input {
        Input::File(path) => match load_cloud(path, Units::Millimetres) {
            Ok((cloud, _)) => answer(rec.recognize(&cloud)),
            Err(e) => (Answer::Failed(e.to_string()), None),
        },
        Input::Cloud(_, cloud) => answer(rec.recognize(cloud)),
    }
}

/// Resident set size, bytes.
fn rss_bytes() -> u64 {
    let pages = std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .unwrap_or(0);
    pages * 4096
}

fn mib(b: u64) -> f64 {
    b as f64 / (1024.0 * 1024.0)
}

fn median_max(v: &mut [f64]) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (0.0, 0.0);
    }
    (v[v.len() / 2], v[v.len() - 1])
}

fn arg(args: &[String], name: &str, default: usize) -> Result<usize, String> {
    match args.iter().position(|a| a == name) {
        None => Ok(default),
        Some(i) => args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("{name} needs a number")),
    }
}

fn inputs(tmp: &Path, sample_only: bool) -> Result<Vec<Input>, String> {
    let mut out = vec![Input::File("data/sample/scenes/conveyor-A.pcd".into())];
    if sample_only {
        return Ok(out);
    }
    let mut tiny: Vec<PathBuf> = std::fs::read_dir("data/tiny/scenes")
        .map_err(|e| format!("data/tiny/scenes: {e} (run from the repository root)"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "pcd"))
        .collect();
    tiny.sort();
    out.extend(tiny.into_iter().map(Input::File));
    let (sample, _) = load_cloud(
        "data/sample/scenes/conveyor-A.pcd".as_ref(),
        Units::Millimetres,
    )
    .map_err(|e| e.to_string())?;
    let mut stray = sample.clone();
    stray.points.insert(500, [1e30, -1e30, 1e30]);
    out.push(Input::Cloud("sample + stray point at 1e30".into(), stray));
    // Broken inputs.
    let truncated = tmp.join("truncated.pcd");
    let bytes = std::fs::read("data/tiny/scenes/tiny-conv-A-000.pcd").map_err(|e| e.to_string())?;
    std::fs::write(&truncated, &bytes[..bytes.len() / 3]).map_err(|e| e.to_string())?;
    let garbage = tmp.join("garbage.pcd");
    std::fs::write(&garbage, b"not a point cloud\x00\xff\x13").map_err(|e| e.to_string())?;
    out.push(Input::File(tmp.join("missing.pcd")));
    out.push(Input::File(truncated));
    out.push(Input::File(garbage));
    out.push(Input::Cloud("empty".into(), PointCloud::default()));
    out.push(Input::Cloud(
        "one point".into(),
        PointCloud {
            points: vec![[1.0, 2.0, 3.0]],
        },
    ));
    let mut metres = sample.clone();
    metres.scale(0.001);
    out.push(Input::Cloud("sample in metres".into(), metres));
    let mut nan = sample;
    nan.points[7][2] = f32::NAN;
    out.push(Input::Cloud("NaN coordinate".into(), nan));
    Ok(out)
}

fn main() -> ExitCode {
    match run() {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("soak: {e}");
            ExitCode::from(2)
        }
    }
}

fn run() -> Result<bool, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let callers = arg(&args, "--callers", 8)?.max(1);
    let calls = arg(&args, "--calls", 125)?.max(1);
    let threads = arg(&args, "--threads", 0)?;
    let serial_rounds = arg(&args, "--serial-rounds", 3)?.max(1);

    let tmp = std::env::temp_dir().join(format!("binpick-soak-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    let inputs = inputs(&tmp, args.iter().any(|a| a == "--sample-only"))?;
    let mut params = Preset::A.params();
    params.runtime.threads = threads;
    let (model, _) = load_cloud("data/sample/models/A.pcd".as_ref(), Units::Millimetres)
        .map_err(|e| e.to_string())?;
    let rec = Recognizer::new(&model, params).map_err(|e| e.to_string())?;
    println!(
        "soak: {} inputs, recognizer with {} thread(s); {callers} callers x {calls} calls",
        inputs.len(),
        rec.threads()
    );

    // Serial: the reference answers, then timed rounds.
    let expected: Vec<Answer> = inputs.iter().map(|i| call(&rec, i).0).collect();
    for (i, a) in inputs.iter().zip(&expected) {
        let what = match a {
            Answer::Found(f) => format!("{} detection(s)", f.0.len()),
            Answer::Failed(e) => format!("error: {e}"),
        };
        println!("  {:<45} {what}", i.name());
    }
    let start = Instant::now();
    let mut serial_mismatch = 0;
    for _ in 0..serial_rounds {
        for (i, e) in inputs.iter().zip(&expected) {
            serial_mismatch += usize::from(call(&rec, i).0 != *e);
        }
    }
    let serial_calls = serial_rounds * inputs.len();
    let serial_s = start.elapsed().as_secs_f64();
    let serial_rate = serial_calls as f64 / serial_s;

    // Concurrent.
    let total = callers * calls;
    let warm_after = (total / 10).max(1);
    let done = AtomicUsize::new(0);
    let rss_warm = Mutex::new(0u64);
    let latencies = Mutex::new(Vec::with_capacity(total));
    // Calls that recognised (not the inputs refused at once): latency, queue wait.
    let recognitions = Mutex::new(Vec::with_capacity(total));
    let mismatches = Mutex::new(Vec::new());
    let start = Instant::now();
    std::thread::scope(|s| {
        for t in 0..callers {
            let (rec, inputs, expected) = (&rec, &inputs, &expected);
            let (done, rss_warm, latencies, recognitions, mismatches) =
                (&done, &rss_warm, &latencies, &recognitions, &mismatches);
            s.spawn(move || {
                for i in 0..calls {
                    let k = (t * calls + i) % inputs.len();
                    let t0 = Instant::now();
                    let (got, queue_ms) = call(rec, &inputs[k]);
                    let latency = t0.elapsed().as_secs_f64() * 1000.0;
                    if got != expected[k] {
                        if let Ok(mut m) = mismatches.lock() {
                            m.push(format!("caller {t} call {i}: {}", inputs[k].name()));
                        }
                    }
                    if let Ok(mut l) = latencies.lock() {
                        l.push(latency);
                    }
                    if let (Some(q), Ok(mut r)) = (queue_ms, recognitions.lock()) {
                        r.push((latency, q));
                    }
                    if done.fetch_add(1, Ordering::SeqCst) + 1 == warm_after {
                        if let Ok(mut w) = rss_warm.lock() {
                            *w = rss_bytes();
                        }
                    }
                }
            });
        }
    });
    let concurrent_s = start.elapsed().as_secs_f64();
    let rss_end = rss_bytes();
    let rss_warm = rss_warm.into_inner().unwrap_or(0);
    let concurrent_rate = total as f64 / concurrent_s;
    let (lat_med, lat_max) = median_max(&mut latencies.into_inner().unwrap_or_default());
    let recognitions = recognitions.into_inner().unwrap_or_default();
    let (rec_med, rec_max) = median_max(&mut recognitions.iter().map(|r| r.0).collect::<Vec<_>>());
    let (q_med, q_max) = median_max(&mut recognitions.iter().map(|r| r.1).collect::<Vec<_>>());
    let mismatches = mismatches.into_inner().unwrap_or_default();
    let growth = rss_end as f64 / rss_warm.max(1) as f64 - 1.0;
    let _ = std::fs::remove_dir_all(&tmp);

    println!(
        "serial:     {serial_calls} calls in {serial_s:.1} s = {serial_rate:.2} calls/s ({serial_mismatch} differing)"
    );
    println!(
        "concurrent: {total} calls in {concurrent_s:.1} s = {concurrent_rate:.2} calls/s ({:.2}x serial), {} differing",
        concurrent_rate / serial_rate,
        mismatches.len()
    );
    println!(
        "latency (call to return, queue included): all calls median {lat_med:.0} ms, max {lat_max:.0} ms; \
         the {} that recognised median {rec_med:.0} ms, max {rec_max:.0} ms, of which queue wait median {q_med:.0} ms, max {q_max:.0} ms",
        recognitions.len()
    );
    println!(
        "resident memory: {:.1} MiB after warm-up ({warm_after} calls), {:.1} MiB at the end ({:+.2} %)",
        mib(rss_warm),
        mib(rss_end),
        100.0 * growth
    );
    for m in mismatches.iter().take(10) {
        println!("  differs: {m}");
    }
    let ok = mismatches.is_empty() && serial_mismatch == 0 && growth < 0.05;
    println!("soak: {}", if ok { "PASS" } else { "FAIL" });
    Ok(ok)
}
