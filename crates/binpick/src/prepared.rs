//! Prepared models on disk: the part (its sampled surface, size and symmetries) and the
//! scene-voting model of each working scale (point-pair table, near-symmetries), written once
//! by `binpick model prepare` so that a controller's first scan does not pay the preparation.
//!
//! A file is a magic line, one JSON header line ([`PreparedHeader`]) and a binary payload
//! (postcard). It is refused, with a message saying what to do, when it was written by
//! another format or binpick version, for other units or voting parameters, or when the
//! model file it was prepared from has changed since (when that file is still there).
//!
//! ```text
//! binpick prepared model\n
//! {"format":1,"binpick_version":"0.1.0","source":"bracket.stl",...}\n
//! <payload_bytes bytes: the part and its voting models>
//! ```

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use binpick_cloud::Units;

use crate::error::{Result, input};
use crate::params::Params;
use crate::part_file::sidecar_path;
use crate::stages::hypotheses::VotingModel;
use crate::stages::part::Part;

/// The first line of every prepared-model file.
const MAGIC: &[u8] = b"binpick prepared model\n";
/// Version of the layout; raised whenever a prepared type changes.
pub const PREPARED_FORMAT: u32 = 6;
/// The extension `binpick model prepare` writes and `load_part` recognises.
pub const PREPARED_EXTENSION: &str = "prepared";

/// Key of one voting model: the working resolution's and the sampling step's bits.
pub(crate) type ModelKey = (u64, u64);

/// Voting models prepared ahead, as read from a prepared-model file.
#[derive(Debug, Default)]
pub(crate) struct PreparedVoting {
    /// [`voting_params_hash`] of the parameters they were prepared with.
    pub params_hash: u64,
    pub models: Vec<(ModelKey, Arc<VotingModel>)>,
}

/// One working scale a file holds a voting model for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PreparedScale {
    /// Working resolution the voting model was built for, mm.
    pub resolution_mm: f64,
    /// Point-pair sampling step at that resolution, mm.
    pub sampling_step_mm: f64,
}

/// What a prepared-model file says about itself (its second line, JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PreparedHeader {
    /// [`PREPARED_FORMAT`] of the writer.
    pub format: u32,
    /// The binpick version that wrote it.
    pub binpick_version: String,
    /// The model file it was prepared from, as given.
    pub source: PathBuf,
    /// FNV-1a 64 of the model file's bytes followed by its sidecar's (hex).
    pub source_hash: String,
    /// Units the model file was read in.
    pub units: Units,
    /// [`voting_params_hash`] of the parameters used (hex).
    pub voting_params_hash: String,
    /// The working scales prepared.
    pub scales: Vec<PreparedScale>,
    /// Length of the payload after the header, bytes.
    pub payload_bytes: u64,
    /// FNV-1a 64 of the payload (hex).
    pub payload_hash: String,
}

#[derive(Serialize, Deserialize)]
struct Payload {
    part: Part,
    models: Vec<(ModelKey, VotingModel)>,
}

/// FNV-1a, 64 bits: a stable hash (unlike `std`'s, it does not change between Rust releases).
fn fnv1a(hash: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(hash, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
    })
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

fn hex(h: u64) -> String {
    format!("{h:016x}")
}

/// Hash of a model file and its sidecar (when there is one): what a prepared model is tied to.
pub fn source_hash(model: &Path) -> Result<u64> {
    let read =
        |p: &Path| std::fs::read(p).map_err(|e| input("model", format!("{}: {e}", p.display())));
    let mut h = fnv1a(FNV_OFFSET, &read(model)?);
    let sidecar = sidecar_path(model);
    if sidecar.exists() {
        h = fnv1a(h, b"\0sidecar\0");
        h = fnv1a(h, &read(&sidecar)?);
    }
    Ok(h)
}

/// Hash of the parameters a voting model's table depends on (`feature_angle_bins`,
/// `alpha_bins`, `spread`, `max_pairs_per_bin`; the lengths are in its scale key).
pub fn voting_params_hash(params: &Params) -> u64 {
    let v = &params.stages().voting;
    let text = format!(
        "feature_angle_bins={} alpha_bins={} spread={:e} max_pairs_per_bin={}",
        v.feature_angle_bins, v.alpha_bins, v.spread, v.max_pairs_per_bin
    );
    fnv1a(FNV_OFFSET, text.as_bytes())
}

/// Whether `path` names a prepared-model file (by its extension).
pub fn is_prepared(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(PREPARED_EXTENSION))
}

/// Writes `part` and its voting `models` to `path`; `source` is the model file they came from.
pub(crate) fn write(
    path: &Path,
    source: &Path,
    units: Units,
    params: &Params,
    part: &Part,
    models: &[(ModelKey, Arc<VotingModel>)],
) -> Result<PreparedHeader> {
    let payload = Payload {
        part: part.clone(),
        models: models.iter().map(|(k, m)| (*k, (**m).clone())).collect(),
    };
    let bytes = postcard::to_stdvec(&payload)
        .map_err(|e| input("prepared model", format!("cannot encode: {e}")))?;
    let header = PreparedHeader {
        format: PREPARED_FORMAT,
        binpick_version: env!("CARGO_PKG_VERSION").to_owned(),
        // Absolute, so the check for a changed model works from any working directory.
        source: std::fs::canonicalize(source).unwrap_or_else(|_| source.to_path_buf()),
        source_hash: hex(source_hash(source)?),
        units,
        voting_params_hash: hex(voting_params_hash(params)),
        scales: models
            .iter()
            .map(|((r, s), _)| PreparedScale {
                resolution_mm: f64::from_bits(*r),
                sampling_step_mm: f64::from_bits(*s),
            })
            .collect(),
        payload_bytes: bytes.len() as u64,
        payload_hash: hex(fnv1a(FNV_OFFSET, &bytes)),
    };
    let line = serde_json::to_string(&header)
        .map_err(|e| input("prepared model", format!("cannot encode the header: {e}")))?;
    let mut out = Vec::with_capacity(MAGIC.len() + line.len() + 1 + bytes.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(line.as_bytes());
    out.push(b'\n');
    out.extend_from_slice(&bytes);
    std::fs::write(path, out)
        .map_err(|e| input("prepared model", format!("{}: {e}", path.display())))?;
    Ok(header)
}

/// Reads only the header of a prepared-model file.
pub fn read_header(path: &Path) -> Result<PreparedHeader> {
    let bytes = std::fs::read(path)
        .map_err(|e| input("prepared model", format!("{}: {e}", path.display())))?;
    Ok(split(path, &bytes)?.0)
}

fn split<'a>(path: &Path, bytes: &'a [u8]) -> Result<(PreparedHeader, &'a [u8])> {
    let bad = |m: String| input("prepared model", format!("{}: {m}", path.display()));
    let rest = bytes.strip_prefix(MAGIC).ok_or_else(|| {
        bad("not a prepared model (no \"binpick prepared model\" first line)".into())
    })?;
    let end = rest
        .iter()
        .position(|b| *b == b'\n')
        .ok_or_else(|| bad("truncated header".into()))?;
    let header: PreparedHeader =
        serde_json::from_slice(&rest[..end]).map_err(|e| bad(format!("unreadable header: {e}")))?;
    Ok((header, &rest[end + 1..]))
}

/// Reads a prepared model for use with `units` and `params`: the part, with its voting models
/// attached (a [`Recognizer`](crate::Recognizer) built on it starts with them).
pub fn read(path: &Path, units: Units, params: &Params) -> Result<(Part, PreparedHeader)> {
    let bytes = std::fs::read(path)
        .map_err(|e| input("prepared model", format!("{}: {e}", path.display())))?;
    let (header, payload) = split(path, &bytes)?;
    let stale = |why: String| {
        input(
            "prepared model",
            format!(
                "{}: {why}; prepare it again (binpick model prepare --model {} --out {})",
                path.display(),
                header.source.display(),
                path.display()
            ),
        )
    };
    let version = env!("CARGO_PKG_VERSION");
    if header.format != PREPARED_FORMAT || header.binpick_version != version {
        return Err(stale(format!(
            "written by binpick {} (format {}), this is binpick {version} (format {PREPARED_FORMAT})",
            header.binpick_version, header.format
        )));
    }
    if header.units != units {
        return Err(stale(format!(
            "prepared from a model in {:?}, asked for {units:?}",
            header.units
        )));
    }
    let params_hash = voting_params_hash(params);
    if header.voting_params_hash != hex(params_hash) {
        return Err(stale(
            "prepared with other voting table parameters (feature_angle_bins, alpha_bins, spread, \
             max_pairs_per_bin) than these"
                .into(),
        ));
    }
    if header.source.exists() && hex(source_hash(&header.source)?) != header.source_hash {
        return Err(stale(format!(
            "{} (or its sidecar) has changed since",
            header.source.display()
        )));
    }
    if payload.len() as u64 != header.payload_bytes
        || hex(fnv1a(FNV_OFFSET, payload)) != header.payload_hash
    {
        return Err(stale(format!(
            "the payload is damaged ({} bytes, header says {})",
            payload.len(),
            header.payload_bytes
        )));
    }
    let Payload { mut part, models } =
        postcard::from_bytes(payload).map_err(|e| stale(format!("undecodable payload: {e}")))?;
    part.prepared = Some(Arc::new(PreparedVoting {
        params_hash,
        models: models.into_iter().map(|(k, m)| (k, Arc::new(m))).collect(),
    }));
    Ok((part, header))
}
