//! Progress on stderr: a bar on a terminal, an info line every tenth of the items otherwise
//! (CI logs). Bars live in the shared [`crate::logging::multi`], so log lines print above them.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

pub struct Progress {
    bar: Option<ProgressBar>,
    total: usize,
    every: usize,
    label: String,
}

impl Progress {
    pub fn new(total: usize, label: &str) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = crate::logging::multi().add(ProgressBar::new(total as u64));
            if let Ok(style) = ProgressStyle::with_template(
                "{prefix} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
            ) {
                b.set_style(style.progress_chars("=> "));
            }
            b.set_prefix(label.to_owned());
            b
        });
        Self {
            bar,
            total,
            every: (total / 10).max(1),
            label: label.to_owned(),
        }
    }

    pub fn step(&self, done: usize, msg: &str) {
        match &self.bar {
            Some(b) => {
                b.set_position(done as u64);
                b.set_message(msg.to_owned());
            }
            None if done % self.every == 0 || done == self.total => {
                tracing::info!("{} {done}/{}: {msg}", self.label, self.total);
            }
            None => {}
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
            crate::logging::multi().remove(b);
        }
    }
}
