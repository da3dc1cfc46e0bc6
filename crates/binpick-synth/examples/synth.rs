//! Generates a preset until `binpick synth` is wired:
//! `cargo run --release -p binpick-synth --example synth -- PRESET OUT_DIR [SEED] [SCENES_PER_GROUP] [POINTS]`
use binpick_synth::{Preset, SynthOptions, generate};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(preset), Some(out)) = (args.first(), args.get(1)) else {
        return Err("usage: synth PRESET OUT_DIR [SEED] [SCENES_PER_GROUP] [POINTS]".into());
    };
    let opts = SynthOptions {
        preset: preset.parse::<Preset>()?,
        out_dir: out.into(),
        seed: args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1),
        scenes_per_group: args.get(3).map(|s| s.parse()).transpose()?,
        points_target: args.get(4).map(|s| s.parse()).transpose()?,
    };
    let summary = generate(&opts, &|done, total| eprint!("\r{done}/{total} scenes"))?;
    eprintln!();
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}
