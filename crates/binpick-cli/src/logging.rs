//! Logging: `tracing` events from the CLI and the libraries, printed on stderr as
//! `binpick: message` (`binpick: warning: ...`, `binpick: error: ...`; below info the level
//! and the event's module: `binpick: DEBUG binpick_eval::dataset: ...`).
//!
//! Verbosity: `-q` shows warnings and errors only, `-qq` errors only, `-v` adds debug events
//! of binpick's crates, `-vv` trace events. `RUST_LOG` (env-filter syntax, e.g.
//! `RUST_LOG=binpick_eval=debug`) replaces the level given by the flags. Log lines never go to
//! stdout, which holds results only. Progress bars and the stage spinner share one
//! `MultiProgress`; a log line is printed above them.

use std::io::{IsTerminal, Write};
use std::sync::{Mutex, OnceLock};

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, FormattedFields};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer};

/// binpick's own crates (module-path prefixes of their events).
const OUR_TARGETS: [&str; 7] = [
    "binpick",
    "binpick_cli",
    "binpick_cloud",
    "binpick_eval",
    "binpick_match",
    "binpick_synth",
    "binpick_viz",
];

/// The bars and spinners on stderr (hidden when stderr is not a terminal).
pub fn multi() -> &'static MultiProgress {
    static MULTI: OnceLock<MultiProgress> = OnceLock::new();
    MULTI.get_or_init(|| {
        if std::io::stderr().is_terminal() {
            MultiProgress::new()
        } else {
            MultiProgress::with_draw_target(ProgressDrawTarget::hidden())
        }
    })
}

/// The spinner whose message follows the library's spans (see [`StageSpinner`]).
fn stage_spinner() -> &'static Mutex<Option<ProgressBar>> {
    static SPINNER: OnceLock<Mutex<Option<ProgressBar>>> = OnceLock::new();
    SPINNER.get_or_init(|| Mutex::new(None))
}

/// The filter for `verbose` - `quiet` (each counted): 0 = info for binpick's crates.
pub fn filter_for(verbose: u8, quiet: u8) -> String {
    let level = match i16::from(verbose) - i16::from(quiet) {
        i16::MIN..=-2 => "error",
        -1 => "warn",
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let ours: Vec<String> = OUR_TARGETS.iter().map(|t| format!("{t}={level}")).collect();
    // Other crates only ever say warnings (errors at -qq).
    let others = if level == "error" { "error" } else { "warn" };
    format!("{others},{}", ours.join(","))
}

/// Installs the subscriber: `RUST_LOG` when set, else the level of the flags.
pub fn init(verbose: u8, quiet: u8) {
    let filter = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => EnvFilter::try_new(&spec).unwrap_or_else(|e| {
            eprintln!(
                "binpick: warning: RUST_LOG={spec:?} is not a valid filter ({e}); using the flags"
            );
            EnvFilter::new(filter_for(verbose, quiet))
        }),
        _ => EnvFilter::new(filter_for(verbose, quiet)),
    };
    let fmt = tracing_subscriber::fmt::layer()
        .event_format(Plain)
        .with_writer(|| AboveBars(Vec::new()));
    // A second init (tests) keeps the first subscriber.
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(fmt)
        .with(StageSpinner)
        .try_init();
}

/// `binpick: ` lines, with the names (and fields) of the spans the event is in.
struct Plain;

impl<S, N> FormatEvent<S, N> for Plain
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut w: Writer<'_>,
        event: &Event<'_>,
    ) -> std::fmt::Result {
        let meta = event.metadata();
        write!(w, "binpick: ")?;
        match *meta.level() {
            Level::ERROR => write!(w, "error: ")?,
            Level::WARN => write!(w, "warning: ")?,
            Level::INFO => {}
            level => write!(w, "{level} {}: ", meta.target())?,
        }
        if let Some(scope) = ctx.event_scope() {
            for span in scope.from_root() {
                write!(w, "{}", span.name())?;
                let ext = span.extensions();
                if let Some(fields) = ext.get::<FormattedFields<N>>()
                    && !fields.is_empty()
                {
                    write!(w, " {fields}")?;
                }
                write!(w, ": ")?;
            }
        }
        ctx.field_format().format_fields(w.by_ref(), event)?;
        writeln!(w)
    }
}

/// One log line, written to stderr above any progress bar when dropped.
struct AboveBars(Vec<u8>);

impl Write for AboveBars {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for AboveBars {
    fn drop(&mut self) {
        let bytes = std::mem::take(&mut self.0);
        multi().suspend(|| {
            let _ = std::io::stderr().write_all(&bytes);
        });
    }
}

/// Shows the name of the innermost binpick span entered (a pipeline stage) on the spinner of
/// a long single recognition.
struct StageSpinner;

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for StageSpinner {
    fn on_enter(&self, id: &tracing::span::Id, ctx: Context<'_, S>) {
        let Some(span) = ctx.span(id) else { return };
        if !span.metadata().target().starts_with("binpick") {
            return;
        }
        if let Ok(guard) = stage_spinner().lock()
            && let Some(bar) = guard.as_ref()
        {
            bar.set_message(span.name().replace('_', " "));
        }
    }
}

/// A spinner on stderr (terminal only) for a long single step: elapsed time and the library's
/// current stage. Cleared when dropped.
pub struct Spinner(Option<ProgressBar>);

impl Spinner {
    pub fn start(prefix: &str) -> Self {
        if !std::io::stderr().is_terminal() {
            return Self(None);
        }
        let bar = multi().add(ProgressBar::new_spinner());
        if let Ok(style) =
            indicatif::ProgressStyle::with_template("{spinner} {prefix} {elapsed} {msg}")
        {
            bar.set_style(style);
        }
        bar.set_prefix(prefix.to_owned());
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        if let Ok(mut guard) = stage_spinner().lock() {
            *guard = Some(bar.clone());
        }
        Self(Some(bar))
    }
}

impl Drop for Spinner {
    fn drop(&mut self) {
        if let Some(bar) = self.0.take() {
            if let Ok(mut guard) = stage_spinner().lock() {
                *guard = None;
            }
            bar.finish_and_clear();
            multi().remove(&bar);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::filter_for;

    #[test]
    fn flags_set_the_level_of_our_crates_only() {
        assert!(filter_for(0, 0).starts_with("warn,binpick=info,"));
        assert!(filter_for(1, 0).contains("binpick_eval=debug"));
        assert!(filter_for(3, 0).contains("binpick=trace"));
        assert!(filter_for(0, 1).contains("binpick_cli=warn"));
        let qq = filter_for(0, 2);
        assert!(
            qq.starts_with("error,") && qq.contains("binpick=error"),
            "{qq}"
        );
        // -v and -q cancel out.
        assert_eq!(filter_for(1, 1), filter_for(0, 0));
    }
}
