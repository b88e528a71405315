//! Puppets brought in at runtime: `POST /puppets` takes a director's PNG,
//! meshes it and loads the puppet on a blocking worker (never on the stage
//! thread or an async worker), keeps the picture and its mesh in the
//! puppets folder, and asks the stage thread to put it on top; an
//! `add_curve` message makes a curve puppet of a stroke a director drew on
//! the page, the same way. Every answer is JSON: the puppet made, with
//! warnings about the picture, or a typed `error` naming the parameter at
//! fault.
//!
//! A picture goes where it covers the puppets on stage least (tiled into
//! free stage space, smaller if need be), and its placement is written
//! beside it, so [`restore_pictures`] brings every kept picture back when
//! the daemon starts again; removing the puppet deletes its files.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::config::AccessRole;
use axum::Extension;
use axum::body::Body;
use axum::extract::{ConnectInfo, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use glam::DVec2;
use puppetry_mesh::build::{MeshOptions, mesh_picture};
use puppetry_mesh::trace::{MAX_JOIN, PictureWarning};
use puppetry_stage::config::{CurveConfig, PuppetConfig, StageConfig};
use puppetry_stage::{Puppet, Stage};
use serde::{Deserialize, Serialize};

use super::guard::Refusal;
use super::origin::{LocalAddr, PeerAddr, own_origin};
use super::people::{Credential, credential};
use super::{Shared, change_lineup};
use crate::lineup::LineupChange;
use crate::protocol::{ErrorCode, ServerMessage};

use crate::protocol::upload::{DEFAULT_VERTICES, MAX_VERTICES, MIN_VERTICES};
use puppetry_limits::net::MAX_UPLOAD_BYTES as MAX_UPLOAD;

/// A new puppet fits in this fraction of the stage (it is never enlarged).
const FIT: f64 = 0.5;

/// Kept pictures a start brings back, at most (the oldest first): each is a
/// mesh loaded and a solver factored before the stage opens.
pub const MAX_RESTORED: usize = 64;
/// Directory entries of the puppets folder a start looks at, at most.
const MAX_SCANNED: usize = 4096;
/// The largest kept mesh file a start reads (20000 vertices are ~1 MiB).
const MAX_MESH_FILE: u64 = 16 << 20;
/// The largest placement file a start reads.
const MAX_PLACEMENT_FILE: u64 = 4096;

/// `POST /puppets?name=…&vertices=…[&x=…&y=…&scale=…]` with the PNG as the
/// body and `Authorization: Bearer TOKEN` (a director's).
pub(super) async fn add(
    State(shared): State<Arc<Shared>>,
    ConnectInfo(PeerAddr(peer)): ConnectInfo<PeerAddr>,
    Extension(LocalAddr(local)): Extension<LocalAddr>,
    Query(query): Query<HashMap<String, String>>,
    headers: HeaderMap,
    body: Body,
) -> Response {
    match add_puppet(&shared, &query, &headers, local, body).await {
        Ok(added) => (StatusCode::OK, added.to_text()).into_response(),
        Err((status, refusal)) => {
            shared.log.warn(&peer.ip().to_string(), || {
                format!("POST /puppets refused: {}", refusal.message)
            });
            (status, refusal.to_text()).into_response()
        }
    }
}

type Refused = (StatusCode, Refusal);

/// A flag held while its owner runs, let go when it is dropped (on every
/// way out: an answer, a refusal, a request the client gave up on).
struct OneAtATime<'a>(&'a std::sync::atomic::AtomicBool);

impl<'a> OneAtATime<'a> {
    fn claim(flag: &'a std::sync::atomic::AtomicBool) -> Option<OneAtATime<'a>> {
        use std::sync::atomic::Ordering;
        flag.compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire)
            .ok()
            .map(|_| OneAtATime(flag))
    }
}

impl Drop for OneAtATime<'_> {
    fn drop(&mut self) {
        self.0.store(false, std::sync::atomic::Ordering::Release);
    }
}

fn refused(status: StatusCode, code: ErrorCode, message: impl Into<String>) -> Refused {
    (status, Refusal::new(code, message))
}

async fn add_puppet(
    shared: &Shared,
    query: &HashMap<String, String>,
    headers: &HeaderMap,
    local: Option<SocketAddr>,
    body: Body,
) -> Result<ServerMessage, Refused> {
    let links = shared
        .links()
        .map_err(|e| refused(StatusCode::NOT_FOUND, ErrorCode::NotFound, e))?;
    check_director(links, headers, local)?;
    // One picture at a time, from its body to its mesh: each at the size
    // limits costs hundreds of MB while it is meshed, and several at once
    // summed them (994 MB). A second meanwhile is answered 429, busy.
    let _meshing = OneAtATime::claim(&links.meshing).ok_or_else(|| {
        refused(
            StatusCode::TOO_MANY_REQUESTS,
            ErrorCode::Busy,
            "another picture is being added; send this one when it is",
        )
    })?;
    let lineup = shared.lineup.borrow().clone();
    let wanted = Wanted::parse(query, &lineup.config)?;
    let png = axum::body::to_bytes(body, MAX_UPLOAD).await.map_err(|_| {
        refused(
            StatusCode::PAYLOAD_TOO_LARGE,
            ErrorCode::TooLarge,
            format!("the picture is larger than {} MiB", MAX_UPLOAD >> 20),
        )
    })?;
    if !png.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Err(refused(
            StatusCode::BAD_REQUEST,
            ErrorCode::BadImage,
            "the file is not a PNG picture (upload a .png, ideally a figure on a transparent background)",
        ));
    }
    let dir = std::path::absolute(&links.puppets_dir).map_err(|e| {
        refused(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Failed,
            format!("puppets folder {}: {e}", links.puppets_dir.display()),
        )
    })?;
    let config = lineup.config.clone();
    let names: Vec<String> = config.puppets.iter().map(|p| p.name.clone()).collect();
    let taken: Vec<[DVec2; 2]> = lineup
        .description
        .puppets
        .iter()
        .map(|p| {
            let rest: Vec<DVec2> = p
                .rest
                .chunks_exact(2)
                .map(|q| DVec2::new(f64::from(q[0]), f64::from(q[1])))
                .collect();
            bounds(&rest)
        })
        .collect();
    let made =
        tokio::task::spawn_blocking(move || make(&dir, &png, wanted, &config, &names, &taken))
            .await
            .map_err(|e| {
                refused(
                    StatusCode::INTERNAL_SERVER_ERROR,
                    ErrorCode::Failed,
                    e.to_string(),
                )
            })??;
    let Made {
        puppet,
        entry,
        warnings,
        join,
    } = made;
    let pieces = puppet.mesh.pieces().len();
    let (vertices, triangles) = (puppet.mesh.vertices().len(), puppet.mesh.triangles().len());
    let name = entry.name.clone();
    let files = [
        entry.image.clone(),
        entry.mesh.clone(),
        placement_file(&entry.image),
    ];
    match change_lineup(shared, LineupChange::Add(Box::new((puppet, entry)))).await {
        Ok(id) => {
            tracing::info!(puppet = id, %name, vertices, "a director added a puppet");
            Ok(ServerMessage::PuppetAdded {
                puppet: id,
                name,
                vertices,
                triangles,
                warnings,
                pieces,
                join,
            })
        }
        Err(refusal) => {
            for file in files {
                let _ = std::fs::remove_file(file);
            }
            let status = if refusal.code == ErrorCode::Busy {
                StatusCode::CONFLICT
            } else {
                StatusCode::INTERNAL_SERVER_ERROR
            };
            Err((status, refusal))
        }
    }
}

/// Only a director adds puppets, from the daemon's own page or an allowed
/// origin: the same rule as the WebSocket's, against the address the
/// connection reached (`local`), never the request's `Host`, which a
/// rebound name (DNS rebinding) sends as it likes.
fn check_director(
    links: &super::StageLinks,
    headers: &HeaderMap,
    local: Option<SocketAddr>,
) -> Result<(), Refused> {
    if let Some(origin) = headers.get(header::ORIGIN) {
        let allowed = &links.people.access().allowed_origins;
        if !own_origin(origin.to_str().unwrap_or(""), local, allowed) {
            return Err(refused(
                StatusCode::FORBIDDEN,
                ErrorCode::Forbidden,
                "this origin may not change the stage (see access.allowed_origins)",
            ));
        }
    }
    let token = super::people::bearer(headers);
    let access = links.people.access();
    match token.and_then(|t| credential(access, t)) {
        None => Err(refused(
            StatusCode::UNAUTHORIZED,
            ErrorCode::BadToken,
            "adding a puppet needs a director's token (Authorization: Bearer TOKEN)",
        )),
        Some(Credential::Person(i)) if access.people[i].role == AccessRole::Director => Ok(()),
        Some(_) => Err(refused(
            StatusCode::FORBIDDEN,
            ErrorCode::Forbidden,
            "add_puppet: not allowed for performers (directors add puppets)",
        )),
    }
}

/// What the request asks for.
#[derive(Debug, Clone)]
struct Wanted {
    name: String,
    vertices: usize,
    /// Where the director asked for it; none: in free stage space.
    at: Option<[f64; 2]>,
    scale: Option<f64>,
    /// Pieces closer than this many pixels are joined into one.
    join: Option<f64>,
}

impl Wanted {
    fn parse(query: &HashMap<String, String>, config: &StageConfig) -> Result<Wanted, Refused> {
        let bad = |field: &str, message: String| {
            (
                StatusCode::BAD_REQUEST,
                Refusal::new(ErrorCode::BadRequest, message).at(field),
            )
        };
        let out_of_range = |field: &str, message: String| {
            (
                StatusCode::BAD_REQUEST,
                Refusal::new(ErrorCode::OutOfRange, message).at(field),
            )
        };
        if let Some(unknown) = query
            .keys()
            .find(|k| !["name", "vertices", "x", "y", "scale", "join"].contains(&k.as_str()))
        {
            return Err(bad(
                unknown,
                format!("{unknown}: not a parameter (name, vertices, x, y, scale, join)"),
            ));
        }
        let number = |field: &str| -> Result<Option<f64>, Refused> {
            match query.get(field) {
                None => Ok(None),
                Some(text) => match text.trim().parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(Some(v)),
                    _ => Err(bad(
                        field,
                        format!("{field}: {text:?} is not a finite number"),
                    )),
                },
            }
        };
        let name = query.get("name").map(|n| n.trim()).unwrap_or("picture");
        if !valid_name(name) {
            return Err(bad(
                "name",
                format!(
                    "name {name:?}: use 1 to 64 letters, digits, spaces, '-', '_' or '.' (not starting with '.')"
                ),
            ));
        }
        let vertices = match number("vertices")? {
            None => DEFAULT_VERTICES,
            Some(n)
                if n.fract() == 0.0 && (MIN_VERTICES as f64..=MAX_VERTICES as f64).contains(&n) =>
            {
                n as usize
            }
            Some(n) => {
                return Err(out_of_range(
                    "vertices",
                    format!(
                        "vertices: {n} is not a whole number from {MIN_VERTICES} to {MAX_VERTICES}"
                    ),
                ));
            }
        };
        let (width, height) = (config.stage.width, config.stage.height);
        let asked = query.contains_key("x") || query.contains_key("y");
        let x = number("x")?.unwrap_or(width / 2.0);
        let y = number("y")?.unwrap_or(height / 2.0);
        for (field, v, size) in [("x", x, width), ("y", y, height)] {
            if !(0.0..=size).contains(&v) {
                return Err(out_of_range(
                    field,
                    format!("{field}: {v} is off the stage (0 to {size})"),
                ));
            }
        }
        let scale = number("scale")?;
        if let Some(s) = scale
            && !(s > 0.0 && s <= 1000.0)
        {
            return Err(out_of_range(
                "scale",
                format!("scale: {s} must be above 0 and at most 1000"),
            ));
        }
        let join = number("join")?;
        if let Some(j) = join
            && !(0.0..=MAX_JOIN).contains(&j)
        {
            return Err(out_of_range(
                "join",
                format!("join: {j} must be 0 to {MAX_JOIN} pixels"),
            ));
        }
        Ok(Wanted {
            name: name.to_string(),
            vertices,
            at: asked.then_some([x, y]),
            scale,
            join,
        })
    }
}

/// The most points a drawn curve may have (the page thins a stroke to a
/// few units between points, and a message holds at most 64 KiB anyway).
pub const MAX_CURVE_POINTS: usize = 4000;

/// A curve puppet from a stroke drawn on the page (stage coordinates),
/// checked, built and loaded on a blocking worker, then put on top.
pub(super) async fn add_curve(
    shared: &Shared,
    name: String,
    points: Vec<[f64; 2]>,
    width: f64,
    colour: String,
) -> Result<ServerMessage, Refusal> {
    let bad = |field: &str, message: String| Refusal::new(ErrorCode::BadRequest, message).at(field);
    let name = name.trim().to_string();
    if !valid_name(&name) {
        return Err(bad(
            "name",
            format!(
                "name {name:?}: use 1 to 64 letters, digits, spaces, '-', '_' or '.' (not starting with '.')"
            ),
        ));
    }
    if points.len() > MAX_CURVE_POINTS {
        return Err(Refusal::new(
            ErrorCode::OutOfRange,
            format!(
                "points: {} points, at most {MAX_CURVE_POINTS}",
                points.len()
            ),
        )
        .at("points"));
    }
    if !(width.is_finite() && width > 0.0 && width <= 200.0) {
        return Err(Refusal::new(
            ErrorCode::OutOfRange,
            format!("width: {width} must be above 0 and at most 200"),
        )
        .at("width"));
    }
    let is_colour = colour.len() == 7
        && colour.starts_with('#')
        && colour[1..].chars().all(|c| c.is_ascii_hexdigit());
    if !is_colour {
        return Err(bad("colour", format!("colour {colour:?} is not #RRGGBB")));
    }
    let lineup = shared.lineup.borrow().clone();
    let config = lineup.config.clone();
    let names: Vec<String> = config.puppets.iter().map(|p| p.name.clone()).collect();
    let name = (1..)
        .map(|n| {
            if n == 1 {
                name.clone()
            } else {
                format!("{name}-{n}")
            }
        })
        .find(|n| !names.contains(n))
        .expect("a free name");
    let curve = CurveConfig {
        points: Some(points),
        svg: None,
        width,
        colour,
        spacing: None,
        peel_rate: 1.5,
        peel_radius: 0.0,
    };
    let made = tokio::task::spawn_blocking(move || -> Result<(Puppet, PuppetConfig), Refusal> {
        // The stroke stays where it was drawn: the puppet's placement puts
        // its ribbon's box centre at `at`, in its own (= stage) units.
        let ribbon = puppetry_stage::curve_rest_mesh("drawn curve", &curve)
            .map_err(|(field, problem)| bad(field.trim_start_matches("curve."), problem))?;
        let (lo, hi) = ribbon
            .vertices()
            .iter()
            .fold((glam::DVec2::MAX, glam::DVec2::MIN), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        let at = (lo + hi) / 2.0;
        let entry = PuppetConfig {
            curve: Some(curve),
            ..PuppetConfig::placed(name, at.into())
        };
        let puppet = Puppet::load(&config, config.puppets.len(), &entry)
            .map_err(|e| bad("points", e.to_string()))?;
        Ok((puppet, entry))
    })
    .await
    .map_err(|e| Refusal::new(ErrorCode::Failed, e.to_string()))??;
    let (puppet, entry) = made;
    let (vertices, triangles) = (puppet.mesh.vertices().len(), puppet.mesh.triangles().len());
    let name = entry.name.clone();
    let id = change_lineup(shared, LineupChange::Add(Box::new((puppet, entry)))).await?;
    tracing::info!(puppet = id, %name, vertices, "a director drew a curve puppet");
    Ok(ServerMessage::PuppetAdded {
        puppet: id,
        name,
        vertices,
        triangles,
        warnings: Vec::new(),
        pieces: 1,
        join: None,
    })
}

fn valid_name(name: &str) -> bool {
    (1..=64).contains(&name.chars().count())
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_' | '.'))
}

/// A puppet made from a picture, ready for the stage thread.
struct Made {
    puppet: Puppet,
    entry: PuppetConfig,
    warnings: Vec<String>,
    /// The gap a join would bridge, when the picture is several pieces.
    join: Option<f64>,
}

/// Keeps the picture under a free name in `dir`, meshes it, writes the
/// mesh beside it and loads the puppet (rig and solver factored here, off
/// the stage thread). A picture that cannot be meshed leaves nothing behind.
fn make(
    dir: &Path,
    png: &[u8],
    wanted: Wanted,
    config: &StageConfig,
    names: &[String],
    taken: &[[DVec2; 2]],
) -> Result<Made, Refused> {
    let failed = |what: &Path, e: std::io::Error| {
        refused(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Failed,
            format!("{}: {e}", what.display()),
        )
    };
    std::fs::create_dir_all(dir).map_err(|e| failed(dir, e))?;
    let stem = |n: usize| {
        let base = wanted.name.replace(' ', "-");
        if n == 1 { base } else { format!("{base}-{n}") }
    };
    let (name, image, mesh_file) = (1..)
        .map(|n| {
            let name = if n == 1 {
                wanted.name.clone()
            } else {
                format!("{}-{n}", wanted.name)
            };
            let stem = stem(n);
            (
                name,
                dir.join(format!("{stem}.png")),
                dir.join(format!("{stem}.mesh.json")),
            )
        })
        .find(|(name, image, mesh)| {
            !names.contains(name)
                && !image.exists()
                && !mesh.exists()
                && !placement_file(image).exists()
        })
        .expect("a free name");
    std::fs::write(&image, png).map_err(|e| failed(&image, e))?;
    let result = mesh_and_load(&image, &mesh_file, &name, &wanted, config, taken);
    if result.is_err() {
        for file in [&image, &mesh_file, &placement_file(&image)] {
            let _ = std::fs::remove_file(file);
        }
    }
    result
}

fn mesh_and_load(
    image: &Path,
    mesh_file: &Path,
    name: &str,
    wanted: &Wanted,
    config: &StageConfig,
    taken: &[[DVec2; 2]],
) -> Result<Made, Refused> {
    let bad_image =
        |message: String| refused(StatusCode::BAD_REQUEST, ErrorCode::BadImage, message);
    let options = MeshOptions {
        target_vertices: Some(wanted.vertices),
        join: wanted.join,
    };
    let meshed = mesh_picture(image, &options).map_err(|e| {
        // The message names the kept file; the page knows it as its upload.
        bad_image(
            e.to_string()
                .replace(&image.display().to_string(), "the picture"),
        )
    })?;
    let join = meshed.warnings.iter().find_map(|w| match w {
        PictureWarning::Pieces { gap, .. } => Some(f64::from(*gap)),
        _ => None,
    });
    let warnings = meshed
        .warnings
        .iter()
        .map(|w| {
            w.to_string()
                .replace(&image.display().to_string(), "the picture")
        })
        .collect();
    std::fs::write(mesh_file, meshed.mesh.to_json()).map_err(|e| {
        refused(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Failed,
            format!("{}: {e}", mesh_file.display()),
        )
    })?;
    let [lo, hi] = bounds(meshed.mesh.vertices());
    let stage = DVec2::new(config.stage.width, config.stage.height);
    let (at, scale) = match wanted.at {
        Some(at) => (at, fit(hi - lo, stage)),
        None => free_spot(hi - lo, stage, taken),
    };
    let entry = PuppetConfig {
        image: image.to_path_buf(),
        mesh: mesh_file.to_path_buf(),
        scale: wanted.scale.unwrap_or(scale),
        ..PuppetConfig::placed(name.to_string(), at)
    };
    let puppet = Puppet::load(config, config.puppets.len(), &entry)
        .map_err(|e| bad_image(format!("the picture's mesh: {e}")))?;
    let placement = Placement {
        name: entry.name.clone(),
        at: entry.at,
        scale: entry.scale,
    };
    let text = serde_json::to_string_pretty(&placement).expect("a placement serialises");
    let file = placement_file(image);
    std::fs::write(&file, text).map_err(|e| {
        refused(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Failed,
            format!("{}: {e}", file.display()),
        )
    })?;
    Ok(Made {
        puppet,
        entry,
        warnings,
        join,
    })
}

/// The smallest box holding `points`: lower left, upper right.
fn bounds(points: &[DVec2]) -> [DVec2; 2] {
    let (lo, hi) = points
        .iter()
        .fold((DVec2::MAX, DVec2::MIN), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    if lo.cmple(hi).all() {
        [lo, hi]
    } else {
        [DVec2::ZERO; 2]
    }
}

/// The scale at which a picture `size` big fits in `FIT` of the stage.
fn fit(size: DVec2, stage: DVec2) -> f64 {
    let size = size.max(DVec2::ONE);
    (FIT * stage.x / size.x)
        .min(FIT * stage.y / size.y)
        .min(1.0)
}

/// Candidate centres per side when looking for free stage space.
const SPOTS: usize = 8;

/// Where on the stage (and at what scale) a picture `size` big covers the
/// puppets in `taken` (their boxes) least: at the size it fits in `FIT`
/// of the stage, or else smaller (down to a third of that), on the first
/// size where a spot covers nothing, the spot nearest the middle. Boxes,
/// not outlines: a figure's box is what a performer reaches for.
fn free_spot(size: DVec2, stage: DVec2, taken: &[[DVec2; 2]]) -> ([f64; 2], f64) {
    let full = fit(size, stage);
    let mut best: Option<(f64, f64, DVec2, f64)> = None;
    for shrink in [1.0, 0.75, 0.55, 0.35] {
        let scale = full * shrink;
        let half = size.max(DVec2::ONE) * scale / 2.0;
        let (lo, hi) = (half, (stage - half).max(half));
        for j in 0..=SPOTS {
            for i in 0..=SPOTS {
                let t = DVec2::new(i as f64, j as f64) / SPOTS as f64;
                let centre = lo + (hi - lo) * t;
                let covered: f64 = taken
                    .iter()
                    .map(|[a, b]| {
                        let overlap =
                            ((centre + half).min(*b) - (centre - half).max(*a)).max(DVec2::ZERO);
                        overlap.x * overlap.y
                    })
                    .sum();
                let off_centre = centre.distance(stage / 2.0);
                if best.is_none_or(|(c, d, _, _)| (covered, off_centre) < (c, d)) {
                    best = Some((covered, off_centre, centre, scale));
                }
            }
        }
        if best.is_some_and(|(covered, ..)| covered == 0.0) {
            break;
        }
    }
    let (_, _, centre, scale) = best.expect("at least one spot");
    (centre.into(), scale)
}

/// What a start needs to put a kept picture back: written beside it as
/// `NAME.puppet.json` when it is added.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Placement {
    name: String,
    at: [f64; 2],
    scale: f64,
}

/// The placement file of a kept picture (`NAME.png` → `NAME.puppet.json`).
fn placement_file(image: &Path) -> PathBuf {
    image.with_extension("puppet.json")
}

/// Why a kept picture is not brought back.
#[derive(Debug, thiserror::Error)]
enum RestoreError {
    #[error("{0}: no mesh beside it (NAME.mesh.json)")]
    NoMesh(String),
    #[error("{file}: {size} bytes, more than {limit}")]
    TooLarge { file: String, size: u64, limit: u64 },
    #[error("{file}: {problem}")]
    Bad { file: String, problem: String },
}

/// Brings back the pictures directors added that `dir` keeps (`NAME.png`,
/// `NAME.mesh.json` and `NAME.puppet.json`; one without a placement file
/// goes in free stage space), oldest first and on top of the stage file's
/// puppets, at most `MAX_RESTORED` of them; each goes into `config` as
/// the lineup's entries do. A file that cannot be read, is too large or
/// does not load is logged and skipped. Blocking: meshes load here.
/// Returns how many came back.
pub fn restore_pictures(config: &mut StageConfig, stage: &mut Stage, dir: &Path) -> usize {
    // Absolute, as a picture added is kept: a relative path in a puppet's
    // entry is the stage file's folder's, and the puppets folder is the
    // working directory's (`--puppets`, default `./puppets`).
    let Ok(dir) = std::path::absolute(dir) else {
        return 0;
    };
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return 0; // no folder yet: nothing was added
    };
    let mut pictures: Vec<(std::time::SystemTime, PathBuf)> = entries
        .take(MAX_SCANNED)
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .map(|p| {
            let time = p
                .metadata()
                .and_then(|m| m.modified())
                .unwrap_or(std::time::UNIX_EPOCH);
            (time, p)
        })
        .collect();
    pictures.sort();
    if pictures.len() > MAX_RESTORED {
        tracing::warn!(
            folder = %dir.display(),
            "{} pictures kept; bringing back the oldest {MAX_RESTORED}",
            pictures.len()
        );
        pictures.truncate(MAX_RESTORED);
    }
    let mut restored = 0;
    for (_, image) in pictures {
        match restore_one(config, stage, &image) {
            Ok(name) => {
                tracing::info!(picture = %image.display(), %name, "a kept picture is back on stage");
                restored += 1;
            }
            Err(e) => tracing::warn!("kept picture not brought back: {e}"),
        }
    }
    restored
}

fn restore_one(
    config: &mut StageConfig,
    stage: &mut Stage,
    image: &Path,
) -> Result<String, RestoreError> {
    let shown = |p: &Path| p.display().to_string();
    let bad = |p: &Path, problem: String| RestoreError::Bad {
        file: shown(p),
        problem,
    };
    let check_size = |p: &Path, limit: u64| -> Result<(), RestoreError> {
        let size = p.metadata().map_err(|e| bad(p, e.to_string()))?.len();
        if size > limit {
            return Err(RestoreError::TooLarge {
                file: shown(p),
                size,
                limit,
            });
        }
        Ok(())
    };
    let stem = image
        .file_stem()
        .and_then(|s| s.to_str())
        .ok_or_else(|| bad(image, "not a plain file name".into()))?;
    let mesh = image.with_file_name(format!("{stem}.mesh.json"));
    if !mesh.is_file() {
        return Err(RestoreError::NoMesh(shown(image)));
    }
    check_size(image, MAX_UPLOAD as u64)?;
    check_size(&mesh, MAX_MESH_FILE)?;
    let placement_path = placement_file(image);
    let placement = if placement_path.is_file() {
        check_size(&placement_path, MAX_PLACEMENT_FILE)?;
        let text = std::fs::read_to_string(&placement_path)
            .map_err(|e| bad(&placement_path, e.to_string()))?;
        let p: Placement =
            serde_json::from_str(&text).map_err(|e| bad(&placement_path, e.to_string()))?;
        let stage_size = [config.stage.width, config.stage.height];
        let on_stage = (0..2).all(|k| (0.0..=stage_size[k]).contains(&p.at[k]));
        if !(valid_name(&p.name) && on_stage && p.scale > 0.0 && p.scale <= 1000.0) {
            return Err(bad(
                &placement_path,
                "name, at or scale out of range".into(),
            ));
        }
        Some(p)
    } else {
        None
    };
    let (at, scale) = match &placement {
        Some(p) => (p.at, p.scale),
        None => {
            let rest = puppetry_mesh::Mesh::load(&mesh).map_err(|e| bad(&mesh, e.to_string()))?;
            let [lo, hi] = bounds(rest.vertices());
            let taken: Vec<[DVec2; 2]> = stage
                .on_stage()
                .map(|p| bounds(p.mesh.vertices()))
                .collect();
            let stage_size = DVec2::new(config.stage.width, config.stage.height);
            free_spot(hi - lo, stage_size, &taken)
        }
    };
    let wanted = placement
        .map(|p| p.name)
        .unwrap_or_else(|| stem.to_string());
    let wanted = if valid_name(&wanted) {
        wanted
    } else {
        "picture".to_string()
    };
    let name = (1..)
        .map(|n| {
            if n == 1 {
                wanted.clone()
            } else {
                format!("{wanted}-{n}")
            }
        })
        .find(|n| !config.puppets.iter().any(|p| &p.name == n))
        .expect("a free name");
    let entry = PuppetConfig {
        image: image.to_path_buf(),
        mesh,
        scale,
        ..PuppetConfig::placed(name.clone(), at)
    };
    let puppet = Puppet::load(config, config.puppets.len(), &entry)
        .map_err(|e| bad(image, e.to_string()))?;
    stage
        .add_puppet(puppet, &entry)
        .map_err(|e| bad(image, e.to_string()))?;
    config.puppets.push(entry);
    Ok(name)
}

/// A removed puppet's kept files go (a picture the daemon keeps for it in
/// `dir`), so a restart does not bring it back; a stage file's puppet's
/// files are never touched.
pub(super) async fn forget(dir: &Path, entry: &PuppetConfig) {
    let Ok(dir) = std::path::absolute(dir) else {
        return;
    };
    if entry.curve.is_some() || entry.image.parent() != Some(dir.as_path()) {
        return;
    }
    for file in [
        entry.image.clone(),
        entry.mesh.clone(),
        placement_file(&entry.image),
    ] {
        if let Err(e) = tokio::fs::remove_file(&file).await
            && e.kind() != std::io::ErrorKind::NotFound
        {
            tracing::warn!(file = %file.display(), "a removed puppet's file stays: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_short_plain_words() {
        assert!(valid_name("fox"));
        assert!(valid_name("red fox_2.v1"));
        assert!(!valid_name(""));
        assert!(!valid_name(".hidden"));
        assert!(!valid_name("../etc/passwd"));
        assert!(!valid_name(&"a".repeat(65)));
    }

    fn overlap(a: [DVec2; 2], b: [DVec2; 2]) -> f64 {
        let o = (a[1].min(b[1]) - a[0].max(b[0])).max(DVec2::ZERO);
        o.x * o.y
    }

    /// Issue 31: each new picture landed on the others at the centre.
    #[test]
    fn new_pictures_go_where_they_cover_no_other() {
        let stage = DVec2::new(1280.0, 720.0);
        // The demo's gingerbread in the middle.
        let mut taken = vec![[DVec2::new(394.0, 60.0), DVec2::new(886.0, 660.0)]];
        for k in 0..6 {
            let size = DVec2::new(120.0, 100.0);
            let (at, scale) = free_spot(size, stage, &taken);
            let half = size * scale / 2.0;
            let at = DVec2::from(at);
            let boxed = [at - half, at + half];
            for (i, other) in taken.iter().enumerate() {
                assert_eq!(overlap(boxed, *other), 0.0, "picture {k} covers puppet {i}");
            }
            assert!(
                boxed[0].cmpge(DVec2::ZERO).all() && boxed[1].cmple(stage).all(),
                "{boxed:?}"
            );
            assert!(scale > 0.0);
            taken.push(boxed);
        }
    }

    #[test]
    fn an_empty_stage_takes_a_picture_in_the_middle_at_its_fit() {
        let stage = DVec2::new(1280.0, 720.0);
        let (at, scale) = free_spot(DVec2::new(2000.0, 1000.0), stage, &[]);
        assert_eq!(at, [640.0, 360.0]);
        assert_eq!(scale, fit(DVec2::new(2000.0, 1000.0), stage));
    }
}
