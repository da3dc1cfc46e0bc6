//! `binpick model inspect`: a part model's size and sampling, and the rotations that map it
//! (almost) onto itself, with the sidecar lines that declare its symmetries.

use std::path::PathBuf;

use anyhow::Result;
use binpick::{Params, SelfMatchKind, Units, inspect_part};

use crate::config::load_part;

#[derive(clap::Args)]
pub struct InspectArgs {
    /// The part model: a scanned cloud (PCD, PLY) or a CAD mesh (STL, OBJ, PLY with faces).
    pub model: PathBuf,
    /// Units of the model file.
    #[arg(long, value_enum, default_value = "mm")]
    pub model_units: Units,
    /// Write the inspection as JSON here (`-` for stdout).
    #[arg(long)]
    pub json: Option<PathBuf>,
}

pub fn run(a: InspectArgs) -> Result<()> {
    let part = load_part(&a.model, a.model_units, &Params::default())?;
    let r = inspect_part(&part)?;
    if let Some(path) = &a.json {
        let text = serde_json::to_string_pretty(&r)?;
        if path.as_os_str() == "-" {
            println!("{text}");
            return Ok(());
        }
        std::fs::write(path, text + "\n")
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    println!("model          {}", a.model.display());
    println!("source         {:?}", r.source);
    println!("points         {}", r.points);
    println!("diameter       {:.2} mm", r.diameter_mm);
    println!(
        "resolution     {:.3} mm (side of the square one point covers)",
        r.spacing_mm
    );
    println!(
        "view area      {:.0} mm^2 (one view of the part)",
        r.view_area_mm2
    );
    match r.curvature_radius_mm {
        Some(c) => println!(
            "curvature      {c:.2} mm typical radius (the scene's normals are fitted over at most this)"
        ),
        None => println!("curvature      mostly flat"),
    }
    println!(
        "declared       {} symmetries (identity included)",
        r.declared_symmetries
    );
    if r.self_matches.is_empty() {
        println!("self-matches   none: no rotation tried maps the part onto itself");
        return Ok(());
    }
    println!(
        "self-matches   (gaps: median / 99th percentile distance of the turned surface to the surface; symmetry when the 99th percentile <= {:.2} mm)",
        r.symmetry_tolerance_mm
    );
    for m in &r.self_matches {
        let (kind, angle) = match (m.kind, m.revolution) {
            (SelfMatchKind::Symmetry, true) => ("symmetry: revolution", "every angle".to_owned()),
            (SelfMatchKind::Symmetry, false) => ("symmetry", format!("{:.1} deg", m.angle_deg)),
            (SelfMatchKind::NearSymmetry, _) => (
                "NEAR-symmetry (a trap, do not declare)",
                format!("{:.1} deg", m.angle_deg),
            ),
        };
        println!(
            "  {kind}: {angle} about ({:.3}, {:.3}, {:.3}) through ({:.2}, {:.2}, {:.2}) mm; gaps {:.2} / {:.2} mm",
            m.axis[0],
            m.axis[1],
            m.axis[2],
            m.point_mm[0],
            m.point_mm[1],
            m.point_mm[2],
            m.median_gap_mm,
            m.p99_gap_mm
        );
        if m.kind == SelfMatchKind::NearSymmetry && m.hides_scanned_side {
            println!(
                "    this turn shows the side the scan never saw: a part lying the other way up \
                 fits the scan as this turn, so recognition withholds first picks (give the CAD \
                 mesh, or set pick_turn_ambiguous where every part lies the scanned side up)"
            );
        }
    }
    // The sidecar that declares what was found.
    let revolution = r
        .self_matches
        .iter()
        .find(|m| m.kind == SelfMatchKind::Symmetry && m.revolution);
    let singles: Vec<String> = r
        .self_matches
        .iter()
        .filter(|m| m.kind == SelfMatchKind::Symmetry && !m.revolution)
        .map(|m| serde_json::to_string(&m.transform))
        .collect::<std::result::Result<_, _>>()?;
    if revolution.is_some() || !singles.is_empty() {
        println!(
            "sidecar        {} could say:",
            binpick::sidecar_path(&a.model).display()
        );
        let mut keys = Vec::new();
        if let Some(m) = revolution {
            keys.push(format!(
                "  \"revolution_axis\": {{ \"point\": {:?}, \"direction\": {:?} }}",
                m.point_mm, m.axis
            ));
        }
        if !singles.is_empty() {
            keys.push(format!(
                "  \"symmetries\": [\n    {}\n  ]",
                singles.join(",\n    ")
            ));
        }
        println!("{{\n{}\n}}", keys.join(",\n"));
    }
    Ok(())
}
