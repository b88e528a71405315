//! Puppets brought in at runtime: `POST /puppets` takes a director's PNG,
//! meshes it and loads the puppet on a blocking worker (never on the stage
//! thread or an async worker), keeps the picture and its mesh in the
//! puppets folder, and asks the stage thread to put it on top; an
//! `add_curve` message makes a curve puppet of a stroke a director drew on
//! the page, the same way. Every answer is JSON: the puppet made, with
//! warnings about the picture, or a typed `error` naming the parameter at
//! fault.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use axum::body::Body;
use axum::extract::{ConnectInfo, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use puppetry_mesh::build::{MeshOptions, mesh_picture};
use puppetry_stage::Puppet;
use puppetry_stage::config::{AccessRole, CurveConfig, PuppetConfig, StageConfig};

use super::edge::{PeerAddr, origin_allowed};
use super::guard::Refusal;
use super::people::{Credential, credential};
use super::{Shared, change_lineup};
use crate::lineup::LineupChange;
use crate::protocol::{ErrorCode, ServerMessage};

/// The largest picture accepted.
pub const MAX_UPLOAD: usize = 16 << 20;

/// The vertex counts a director may ask for: enough to bend, few enough
/// that the stage keeps its frame rate.
pub const MIN_VERTICES: usize = 50;
pub const MAX_VERTICES: usize = 20_000;
pub const DEFAULT_VERTICES: usize = 1000;

/// A new puppet fits in this fraction of the stage (it is never enlarged).
const FIT: f64 = 0.5;

/// `POST /puppets?name=…&vertices=…[&x=…&y=…&scale=…]` with the PNG as the
/// body and `Authorization: Bearer TOKEN` (a director's).
pub(super) async fn add(
    State(shared): State<Arc<Shared>>,
    ConnectInfo(PeerAddr(peer)): ConnectInfo<PeerAddr>,
    Query(query): Query<HashMap<String, String>>,
    headers: HeaderMap,
    body: Body,
) -> Response {
    match add_puppet(&shared, &query, &headers, body).await {
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

fn refused(status: StatusCode, code: ErrorCode, message: impl Into<String>) -> Refused {
    (status, Refusal::new(code, message))
}

async fn add_puppet(
    shared: &Shared,
    query: &HashMap<String, String>,
    headers: &HeaderMap,
    body: Body,
) -> Result<ServerMessage, Refused> {
    let links = shared
        .links()
        .map_err(|e| refused(StatusCode::NOT_FOUND, ErrorCode::NotFound, e))?;
    check_director(links, headers)?;
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
    let made = tokio::task::spawn_blocking(move || make(&dir, &png, wanted, &config, &names))
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
    } = made;
    let (vertices, triangles) = (puppet.mesh.vertices().len(), puppet.mesh.triangles().len());
    let name = entry.name.clone();
    let files = [entry.image.clone(), entry.mesh.clone()];
    match change_lineup(shared, LineupChange::Add(Box::new((puppet, entry)))).await {
        Ok(id) => {
            tracing::info!(puppet = id, %name, vertices, "a director added a puppet");
            Ok(ServerMessage::PuppetAdded {
                puppet: id,
                name,
                vertices,
                triangles,
                warnings,
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
/// origin (the same rules as the WebSocket's).
fn check_director(links: &super::StageLinks, headers: &HeaderMap) -> Result<(), Refused> {
    if let Some(origin) = headers.get(header::ORIGIN) {
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        let allowed = &links.people.access().allowed_origins;
        if !origin_allowed(origin.to_str().unwrap_or(""), host, allowed) {
            return Err(refused(
                StatusCode::FORBIDDEN,
                ErrorCode::Forbidden,
                "this origin may not change the stage (see access.allowed_origins)",
            ));
        }
    }
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim);
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
    at: [f64; 2],
    scale: Option<f64>,
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
            .find(|k| !["name", "vertices", "x", "y", "scale"].contains(&k.as_str()))
        {
            return Err(bad(
                unknown,
                format!("{unknown}: not a parameter (name, vertices, x, y, scale)"),
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
        Ok(Wanted {
            name: name.to_string(),
            vertices,
            at: [x, y],
            scale,
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
        .find(|(name, image, mesh)| !names.contains(name) && !image.exists() && !mesh.exists())
        .expect("a free name");
    std::fs::write(&image, png).map_err(|e| failed(&image, e))?;
    let result = mesh_and_load(&image, &mesh_file, &name, &wanted, config);
    if result.is_err() {
        let _ = std::fs::remove_file(&image);
        let _ = std::fs::remove_file(&mesh_file);
    }
    result
}

fn mesh_and_load(
    image: &Path,
    mesh_file: &Path,
    name: &str,
    wanted: &Wanted,
    config: &StageConfig,
) -> Result<Made, Refused> {
    let bad_image =
        |message: String| refused(StatusCode::BAD_REQUEST, ErrorCode::BadImage, message);
    let options = MeshOptions {
        target_vertices: Some(wanted.vertices),
    };
    let meshed = mesh_picture(image, &options).map_err(|e| {
        // The message names the kept file; the page knows it as its upload.
        bad_image(
            e.to_string()
                .replace(&image.display().to_string(), "the picture"),
        )
    })?;
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
    let (lo, hi) = meshed
        .mesh
        .vertices()
        .iter()
        .fold((glam::DVec2::MAX, glam::DVec2::MIN), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    let size = (hi - lo).max(glam::DVec2::splat(1.0));
    let fit = (FIT * config.stage.width / size.x)
        .min(FIT * config.stage.height / size.y)
        .min(1.0);
    let entry = PuppetConfig {
        image: image.to_path_buf(),
        mesh: mesh_file.to_path_buf(),
        scale: wanted.scale.unwrap_or(fit),
        ..PuppetConfig::placed(name.to_string(), wanted.at)
    };
    let puppet = Puppet::load(config, config.puppets.len(), &entry)
        .map_err(|e| bad_image(format!("the picture's mesh: {e}")))?;
    Ok(Made {
        puppet,
        entry,
        warnings,
    })
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
}
