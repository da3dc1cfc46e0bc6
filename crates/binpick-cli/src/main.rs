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
            eprintln!("binpick: error: {}", chain_message(&e));
            ExitCode::FAILURE
        }
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
}
