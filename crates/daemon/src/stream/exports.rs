//! Downloads of takes from the web page: the take file itself, or an export
//! of it (glTF binary, video, Spine JSON) made on request. An export runs
//! on a thread of its own at a lower scheduling priority (nice 10, which its
//! worker threads inherit), so it never competes with the stage thread for
//! a core; its progress goes to every page as `export` messages. One export
//! runs at a time: a second request is answered 429.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use puppetry_export::ExportError;
use puppetry_export::take::{ExportRequest, TakeExportError, export_take_with};

use super::Shared;
use crate::protocol::{ExportState, ServerMessage};

/// Formats a browser can download as one file (a PNG sequence is a folder:
/// `puppetry export` makes those).
const DOWNLOADABLE: [(&str, &str, &str); 5] = [
    ("glb", "glb", "model/gltf-binary"),
    ("mp4", "mp4", "video/mp4"),
    ("mov", "mov", "video/quicktime"),
    ("webm", "webm", "video/webm"),
    ("spine", "json", "application/json"),
];

/// `GET /takes/NAME.take`: the take file.
pub async fn take_file(State(shared): State<Arc<Shared>>, Path(file): Path<String>) -> Response {
    let Some(name) = file.strip_suffix(".take") else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    let Ok(links) = shared.links() else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    let Ok(path) = crate::takes::take_path(&links.takes_dir, name) else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    match tokio::fs::read(&path).await {
        Ok(bytes) => attachment(Body::from(bytes), "application/octet-stream", &file),
        Err(_) => plain(StatusCode::NOT_FOUND, "not found"),
    }
}

/// `GET /takes/NAME/export?format=glb&fps=30&size=1280x720&from=S&to=S`.
pub async fn export(
    State(shared): State<Arc<Shared>>,
    Path(name): Path<String>,
    Query(query): Query<HashMap<String, String>>,
) -> Response {
    let Ok(links) = shared.links() else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    let Ok(take) = crate::takes::take_path(&links.takes_dir, &name) else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    if !take.exists() {
        return plain(StatusCode::NOT_FOUND, &format!("no take {name}"));
    }
    let request = match parse(&query, &name) {
        Ok(r) => r,
        Err(problem) => return plain(StatusCode::BAD_REQUEST, &problem),
    };
    let (format, extension, mime) = request;
    if let Err(problem) = check_numbers(&query, format) {
        return plain(StatusCode::BAD_REQUEST, &problem);
    }
    if links.exporting.swap(true, Ordering::AcqRel) {
        return plain(
            StatusCode::TOO_MANY_REQUESTS,
            "an export is running; try again when it ends",
        );
    }
    let out = std::env::temp_dir().join(format!(
        "puppetry-export-{}-{name}.{extension}",
        std::process::id()
    ));
    let fps = number(&query, "fps").unwrap_or(Ok(30.0));
    let (width, height) = match query.get("size").map(|s| size(s)) {
        Some(Ok(s)) => s,
        Some(Err(p)) => {
            links.exporting.store(false, Ordering::Release);
            return plain(StatusCode::BAD_REQUEST, &p);
        }
        None => (1280, 720),
    };
    let (Ok(fps), Ok(from), Ok(to)) = (
        fps,
        number(&query, "from").transpose(),
        number(&query, "to").transpose(),
    ) else {
        links.exporting.store(false, Ordering::Release);
        return plain(StatusCode::BAD_REQUEST, "fps, from and to must be numbers");
    };
    let export = ExportRequest {
        take,
        config: std::path::PathBuf::new(),
        format: format.to_string(),
        fps,
        from,
        to,
        size: (width, height),
        output: out.clone(),
    };
    let (done, finished) = tokio::sync::oneshot::channel();
    let runner = shared.clone();
    // The stage file with any puppets added since: the take may have them.
    let config = shared.lineup.borrow().config.clone();
    let label = name.clone();
    let started = std::thread::Builder::new()
        .name(format!("export {name}"))
        .spawn(move || {
            lower_priority();
            // A relay mounts no export route: this is the stage.
            let Ok(links) = runner.links() else {
                return;
            };
            let mut progress = Broadcast {
                links,
                take: label.clone(),
                format: export.format.clone(),
                shown: usize::MAX,
            };
            // A flag error is the request's fault: a 400 naming the parameter.
            let result = export_take_with(&export, &config, &mut progress).map_err(|e| match e {
                TakeExportError::Export(ExportError::Flag { flag, problem }) => {
                    (true, format!("{}: {problem}", flag.trim_start_matches('-')))
                }
                other => (false, other.to_string()),
            });
            links.export_state.send_replace(Arc::from(
                ServerMessage::Export(ExportState {
                    take: label,
                    format: export.format.clone(),
                    done: 1,
                    total: 1,
                    finished: true,
                    error: result.as_ref().err().map(|(_, e)| e.clone()),
                })
                .to_text(),
            ));
            links.exporting.store(false, Ordering::Release);
            let _ = done.send(result);
            crate::memory::give_back_freed();
        });
    if started.is_err() {
        links.exporting.store(false, Ordering::Release);
        return plain(StatusCode::INTERNAL_SERVER_ERROR, "cannot start an export");
    }
    match finished.await {
        Ok(Ok(_)) => {
            let bytes = tokio::fs::read(&out).await;
            let _ = tokio::fs::remove_file(&out).await;
            // A Spine export leaves its pictures beside the JSON.
            if let Some(prefix) = out.file_name().map(|n| n.to_string_lossy().into_owned())
                && let Ok(mut entries) = tokio::fs::read_dir(std::env::temp_dir()).await
            {
                while let Ok(Some(e)) = entries.next_entry().await {
                    if e.file_name().to_string_lossy().starts_with(&prefix) {
                        let _ = tokio::fs::remove_file(e.path()).await;
                    }
                }
            }
            match bytes {
                Ok(bytes) => attachment(Body::from(bytes), mime, &format!("{name}.{extension}")),
                Err(e) => plain(StatusCode::INTERNAL_SERVER_ERROR, &e.to_string()),
            }
        }
        Ok(Err((true, problem))) => plain(StatusCode::BAD_REQUEST, &problem),
        Ok(Err((false, problem))) => plain(StatusCode::UNPROCESSABLE_ENTITY, &problem),
        Err(_) => plain(StatusCode::INTERNAL_SERVER_ERROR, "the export stopped"),
    }
}

type Parsed = (&'static str, &'static str, &'static str);

fn parse(query: &HashMap<String, String>, name: &str) -> Result<Parsed, String> {
    let format = query
        .get("format")
        .map(String::as_str)
        .ok_or("format: required (glb, mp4, mov, webm or spine)")?;
    DOWNLOADABLE
        .iter()
        .find(|(f, _, _)| *f == format)
        .copied()
        .ok_or_else(|| {
            format!(
                "format {format:?} of {name}: the page downloads glb, mp4, mov, webm or spine (png sequences: puppetry export)"
            )
        })
}

/// The query's numbers, checked here so a bad one is a 400 naming the
/// parameter (the exporters name command-line flags).
fn check_numbers(query: &HashMap<String, String>, format: &str) -> Result<(), String> {
    let get = |key: &str| match number(query, key) {
        None => Ok(None),
        Some(Ok(v)) if v.is_finite() => Ok(Some(v)),
        Some(_) => Err(format!("{key}: not a finite number")),
    };
    if let Some(fps) = get("fps")?
        && !(fps > 0.0 && fps <= 1000.0)
    {
        return Err(format!("fps: {fps} is not a frame rate from 0 to 1000"));
    }
    if let (Some(from), Some(to)) = (get("from")?, get("to")?)
        && from >= to
    {
        return Err(format!("to: {to} s is not after from ({from} s)"));
    }
    if let Some(text) = query.get("size") {
        let (w, h) = size(text)?;
        if w == 0 || h == 0 || w > 16384 || h > 16384 {
            return Err(format!("size: {text} is not from 1x1 to 16384x16384"));
        }
        if format == "mp4" && (w % 2 == 1 || h % 2 == 1) {
            return Err(format!(
                "size: {text}: H.264 needs an even width and height"
            ));
        }
    }
    Ok(())
}

fn number(query: &HashMap<String, String>, key: &str) -> Option<Result<f64, ()>> {
    query.get(key).map(|v| v.parse::<f64>().map_err(|_| ()))
}

fn size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("size {text:?}: expected WIDTHxHEIGHT");
    let (w, h) = text.split_once('x').ok_or_else(bad)?;
    Ok((w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?))
}

/// Nice 10 for this thread (and the threads it starts): the stage thread
/// and the clients come first.
fn lower_priority() {
    // SAFETY: gettid and setpriority have no memory-safety preconditions.
    unsafe {
        let tid = libc::gettid();
        libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 10);
    }
}

/// Export progress as `export` messages, once per percent.
struct Broadcast<'a> {
    links: &'a super::StageLinks,
    take: String,
    format: String,
    shown: usize,
}

impl puppetry_export::Progress for Broadcast<'_> {
    fn step(&mut self, done: usize, total: usize) {
        let percent = (done * 100).checked_div(total).unwrap_or(100);
        if percent == self.shown {
            return;
        }
        self.shown = percent;
        self.links.export_state.send_replace(Arc::from(
            ServerMessage::Export(ExportState {
                take: self.take.clone(),
                format: self.format.clone(),
                done,
                total,
                finished: false,
                error: None,
            })
            .to_text(),
        ));
    }
}

fn attachment(body: Body, mime: &str, file: &str) -> Response {
    let mut response = body.into_response();
    let headers = response.headers_mut();
    if let Ok(v) = HeaderValue::from_str(mime) {
        headers.insert(header::CONTENT_TYPE, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("attachment; filename=\"{file}\"")) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    response
}

fn plain(status: StatusCode, text: &str) -> Response {
    (status, text.to_string()).into_response()
}
