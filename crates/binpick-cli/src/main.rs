//! `binpick`: recognise parts in bin scans (millimetres), evaluate against ground truth,
//! generate thesis-like datasets.
//!
//! Exit codes: 0 success, 1 failure (bad input, PCL error), 2 usage error, 3 the time budget
//! ran out (`recognize`, `replay`: the parts verified before it are printed and written, and
//! the JSON says where it stopped). Results go to stdout (and files); logs and progress bars
//! go to stderr (`-v`, `-q`, `RUST_LOG`: see [`logging`]).
// The argument structs' doc comments are clap's `--help` text, where `<name>` is a
// placeholder to print as written, not an HTML tag.
#![allow(rustdoc::invalid_html_tags)]

mod bench;
mod check;
mod config;
mod eval;
mod inspect;
mod logging;
mod model;
mod plots;
mod progress;
mod recognize;
mod replay;
mod show;
mod synth;
mod table;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Exit codes, as `--help` prints them.
const EXIT_CODES: &str = "Exit codes: 0 success; 1 failure (missing or corrupt file, bad \
parameter, PCL error); 2 usage error; 3 the time budget (--time-budget-ms) ran out: the parts \
verified before it are printed and written, and the JSON's \"interrupted\" says where it stopped.";

/// The exit code of a run whose time budget ran out (results written, possibly incomplete).
const EXIT_BUDGET: u8 = 3;

/// How a command ended, when it did not fail.
pub enum Done {
    /// Everything was searched.
    Complete,
    /// A time budget ran out: the results written are what was verified before it.
    BudgetExhausted,
}

#[derive(Parser)]
#[command(
    name = "binpick",
    version,
    about = "Bin-picking pose retrieval over PCL (thesis Algorithms 1 and 2). Units: millimetres.",
    after_help = EXIT_CODES
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log lines on stderr: -v debug, -vv trace (binpick's crates). RUST_LOG (e.g.
    /// RUST_LOG=binpick_eval=debug) replaces -v/-q when set.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Fewer log lines on stderr: -q warnings and errors only, -qq errors only. Results on
    /// stdout are unchanged.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    quiet: u8,
}

#[derive(Subcommand)]
enum Command {
    /// Find every instance of a model in a scene and rank them for picking.
    #[command(after_help = table::COLUMNS_HELP)]
    Recognize(recognize::Args),
    /// Evaluate on a labelled dataset and print the thesis's result table (5.5.2).
    Eval(eval::Args),
    /// Run recognition over recorded scans without ground truth.
    Replay(replay::Args),
    /// Judge given poses against a scene as the scene-voting engine judges its hypotheses
    /// (a taught pose, another tool's, a part `recognize` did not report): why it would be
    /// refused.
    Check(check::Args),
    /// Time each stage over repeated runs (medians per scene).
    Bench(bench::Args),
    /// Generate a thesis-like dataset with ground truth (physics piles, simulated scanner).
    Synth(synth::Args),
    /// Render a saved result JSON as PNG (and optionally a labelled PLY).
    Show(show::Args),
    /// Part models: `inspect` (size, resolution, symmetries), `prepare` and `info` (kept on disk).
    Model(model::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    logging::init(cli.verbose, cli.quiet);
    let complete = |r: anyhow::Result<()>| r.map(|()| Done::Complete);
    let result = match cli.command {
        Command::Recognize(a) => recognize::run(a),
        Command::Eval(a) => complete(eval::run(a)),
        Command::Replay(a) => replay::run(a),
        Command::Check(a) => complete(check::run(a)),
        Command::Bench(a) => complete(bench::run(a)),
        Command::Synth(a) => complete(synth::run(a)),
        Command::Show(a) => complete(show::run(a)),
        Command::Model(a) => complete(model::run(a)),
    };
    match result {
        Ok(Done::Complete) => ExitCode::SUCCESS,
        Ok(Done::BudgetExhausted) => ExitCode::from(EXIT_BUDGET),
        Err(e) => {
            eprintln!("binpick: error: {}{}", chain_message(&e), flag_hint(&e));
            ExitCode::FAILURE
        }
    }
}

/// The command-line flag for a library error that names a parameter field (the library
/// speaks of fields, the CLI adds the flag).
fn flag_hint(e: &anyhow::Error) -> &'static str {
    let kind = e
        .chain()
        .find_map(|c| c.downcast_ref::<binpick::Error>())
        .map(binpick::Error::kind);
    match kind {
        Some(binpick::ErrorKind::Input(binpick::InputKind::WrongUnits)) => {
            " (on the command line: --units m for the scene, --model-units m for the model)"
        }
        _ => "",
    }
}

/// The error and its causes as "a: b: c", leaving out a cause whose text the message before
/// it already ends with (binpick's error types print their source inline).
fn chain_message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::chain_message;

    #[test]
    fn causes_printed_inline_are_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(io)
            .context("x.pcd: no such file")
            .context("cannot load the model");
        assert_eq!(
            chain_message(&e),
            "cannot load the model: x.pcd: no such file"
        );
        let plain = anyhow::anyhow!("inner").context("outer");
        assert_eq!(chain_message(&plain), "outer: inner");
    }

    #[test]
    fn wrong_units_get_the_flag_that_fixes_them() {
        // A 50 mm wavy patch written in metres.
        let metres = binpick::PointCloud::new(
            (0..400)
                .map(|k| {
                    let (i, j) = ((k % 20) as f32, (k / 20) as f32);
                    [
                        0.0025 * i,
                        0.0025 * j,
                        0.005 * (0.5 * i).sin() * (0.3 * j).cos(),
                    ]
                })
                .collect(),
        );
        let e = binpick::Recognizer::new(&metres, binpick::Params::default()).unwrap_err();
        assert_eq!(
            e.kind(),
            binpick::ErrorKind::Input(binpick::InputKind::WrongUnits),
            "{e}"
        );
        let e = anyhow::Error::new(e).context("cannot prepare the model");
        assert!(super::flag_hint(&e).contains("--model-units m"));
        assert_eq!(super::flag_hint(&anyhow::anyhow!("other")), "");
    }
}
