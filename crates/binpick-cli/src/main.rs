//! `binpick`: recognise parts in bin scans (millimetres), evaluate against ground truth,
//! generate thesis-like datasets.
//!
//! Exit codes: 0 success, 1 failure (bad input, PCL error, budget exceeded), 2 usage error.
//! Results go to stdout (and files); logs and progress bars go to stderr.

mod bench;
mod config;
mod eval;
mod plots;
mod progress;
mod recognize;
mod replay;
mod show;
mod synth;
mod table;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "binpick",
    version,
    about = "Bin-picking pose retrieval over PCL (thesis Algorithms 1 and 2). Units: millimetres."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Find every instance of a model in a scene and rank them for picking.
    Recognize(recognize::Args),
    /// Evaluate on a labelled dataset and print the thesis's result table (5.5.2).
    Eval(eval::Args),
    /// Run recognition over recorded scans without ground truth.
    Replay(replay::Args),
    /// Time each stage over repeated runs (medians per scene).
    Bench(bench::Args),
    /// Generate a thesis-like dataset with ground truth (physics piles, simulated scanner).
    Synth(synth::Args),
    /// Render a saved result JSON as PNG (and optionally a labelled PLY).
    Show(show::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Recognize(a) => recognize::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Replay(a) => replay::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Synth(a) => synth::run(a),
        Command::Show(a) => show::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("binpick: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
