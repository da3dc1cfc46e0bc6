//! Charts for `binpick eval --plots` (rendering in binpick-viz, once available).

use std::path::Path;

use anyhow::{Result, bail};
use binpick::evaluate::EvalRun;

pub fn eval_plots(_dir: &Path, _preset: &str, _run: &EvalRun) -> Result<()> {
    bail!("--plots is not available in this build yet")
}
