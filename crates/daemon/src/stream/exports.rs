//! Downloads of takes from the web page: the take file itself, or an export
//! of it (glTF binary, video, Spine JSON) made on request. An export runs
//! on a thread of its own at a lower scheduling priority (nice 10, which its
//! worker threads inherit), so it never competes with the stage thread for
//! a core; its progress goes to every page as `export` messages. One export
//! runs at a time: a second request is answered 429.
//!
//! Both need a director's token as `Authorization: Bearer TOKEN` (401
//! without one, 403 for another role's): a header, not a cookie or a query,
//! so a foreign page's `<img>` or link — which can fire a GET but not set a
//! header — can neither download a take nor keep the export slot busy.
//! What is served names no folder of the daemon's: the take's header is
//! served with its `stage_file` cut to the file's name (the file on disk is
//! left as recorded), and error messages drop the takes folder.
//!
//! An export's cost is computed from the take before anything is read into
//! memory (`puppetry_export::budget`): past a limit it is a 413 naming the
//! size and the limit. It is written into a private folder made for it
//! (random name, this user's only), streamed from disk as the answer, and
//! the folder removed; nothing is written at a name a stranger could
//! guess.

use std::collections::HashMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use crate::config::AccessRole;
use puppetry_export::budget::BudgetError;
use puppetry_export::format::Format;
use puppetry_export::take::{ExportRequest, TakeExportError, export_take_with};
use puppetry_export::{ExportError, Scratch};
use puppetry_take::{TakeError, TakeReader, TakeWriter};

use super::Shared;
use super::people::{Credential, credential};
use crate::outputs::Published;
use crate::protocol::{ExportState, ServerMessage};

/// The export's query parameters; any other is refused (400).
const PARAMETERS: [&str; 5] = ["format", "fps", "size", "from", "to"];

/// Why a take could not be served.
#[derive(Debug, thiserror::Error)]
enum DownloadError {
    #[error(transparent)]
    Take(#[from] TakeError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error("{file}: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
}

/// Only a director downloads takes and exports: `Authorization: Bearer
/// TOKEN`, checked as the WebSocket's hello is (every token compared in
/// constant time). The answer to anyone else.
fn not_a_director(links: &super::StageLinks, headers: &HeaderMap) -> Option<Response> {
    let token = super::people::bearer(headers);
    let access = links.people.access();
    match token.and_then(|t| credential(access, t)) {
        Some(Credential::Person(i)) if access.people[i].role == AccessRole::Director => None,
        None => {
            let mut answer = plain(
                StatusCode::UNAUTHORIZED,
                "downloading a take needs a director's token (Authorization: Bearer TOKEN)",
            );
            answer.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"puppetry\""),
            );
            Some(answer)
        }
        Some(_) => Some(plain(
            StatusCode::FORBIDDEN,
            "downloading a take: not allowed for performers (directors download takes)",
        )),
    }
}

/// `GET /takes/NAME.take`: the take file, its header's `stage_file` cut to
/// the stage file's name.
pub async fn take_file(
    State(shared): State<Arc<Shared>>,
    Path(file): Path<String>,
    headers: HeaderMap,
) -> Response {
    let Some(name) = file.strip_suffix(".take") else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    let Ok(links) = shared.links() else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    if let Some(refused) = not_a_director(links, &headers) {
        return refused;
    }
    let Ok(path) = crate::takes::take_path(&links.takes_dir, name) else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    if !path.is_file() {
        return plain(StatusCode::NOT_FOUND, &format!("no take {name}"));
    }
    let takes_dir = links.takes_dir.clone();
    let served = tokio::task::spawn_blocking(move || served_take(&path)).await;
    match served {
        Ok(Ok((head, rest, length))) => {
            use futures_util::StreamExt;
            use tokio::io::AsyncReadExt;
            let total = head.len() as u64 + length;
            let rest = tokio::fs::File::from_std(rest).take(length);
            let head = futures_util::stream::once(async move {
                Ok::<_, std::io::Error>(bytes::Bytes::from(head))
            });
            let body = Body::from_stream(head.chain(read_stream(rest)));
            let mut answer = attachment(body, "application/octet-stream", &file);
            answer
                .headers_mut()
                .insert(header::CONTENT_LENGTH, HeaderValue::from(total));
            answer
        }
        Ok(Err(e)) => plain(
            StatusCode::UNPROCESSABLE_ENTITY,
            &without_folders(&e.to_string(), &takes_dir, None),
        ),
        Err(_) => plain(
            StatusCode::INTERNAL_SERVER_ERROR,
            "reading the take stopped",
        ),
    }
}

/// The take at `path` as served: its magic and header record, re-encoded
/// with `stage_file` cut to its file name, and the file opened at the
/// record after the header with the bytes left from there (as long as the
/// file was when opened: a take still recording is served as far as it
/// got).
fn served_take(path: &FsPath) -> Result<(Vec<u8>, std::fs::File, u64), DownloadError> {
    use std::io::{Read, Seek, SeekFrom};
    let io = |source| DownloadError::Io {
        file: path.display().to_string(),
        source,
    };
    let mut header = TakeReader::open(path)?.header;
    header.stage_file = FsPath::new(&header.stage_file)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    // The header re-encoded the take format's own way, through a writer.
    let scratch = Scratch::new()?;
    let rewritten = scratch.path().join("header.take");
    let mut writer = TakeWriter::create(&rewritten, &header)?;
    writer.flush()?;
    drop(writer);
    let head = std::fs::read(&rewritten).map_err(|source| DownloadError::Io {
        file: rewritten.display().to_string(),
        source,
    })?;
    // The header record on disk: after the magic, length (of kind and
    // payload), kind, payload, CRC (docs/takes.md).
    let mut file = std::fs::File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    let mut start = [0u8; 12];
    file.read_exact(&mut start).map_err(io)?;
    let length = u32::from_le_bytes([start[8], start[9], start[10], start[11]]) as u64;
    let after_header = puppetry_take::MAGIC.len() as u64 + 4 + length + 4;
    file.seek(SeekFrom::Start(after_header)).map_err(io)?;
    Ok((head, file, size.saturating_sub(after_header)))
}

/// A file read as a stream of chunks, ending at its end or its first error.
fn read_stream(
    file: impl tokio::io::AsyncRead + Send + Unpin + 'static,
) -> impl futures_util::Stream<Item = std::io::Result<bytes::Bytes>> + Send + 'static {
    use tokio::io::AsyncReadExt;
    futures_util::stream::unfold(Some(file), |file| async move {
        let mut file = file?;
        let mut buf = bytes::BytesMut::zeroed(1 << 16);
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok(buf.freeze()), Some(file)))
            }
            Err(e) => Some((Err(e), None)),
        }
    })
}

/// `message` without the daemon's folders: the takes folder and the
/// export's scratch folder (their paths mean nothing to a page, and tell a
/// stranger where things are).
fn without_folders(message: &str, takes_dir: &FsPath, scratch: Option<&FsPath>) -> String {
    let mut text = message.to_string();
    for dir in std::iter::once(takes_dir).chain(scratch) {
        let dir = dir.display().to_string();
        if !dir.is_empty() {
            text = text.replace(&format!("{dir}/"), "").replace(&dir, "");
        }
    }
    text
}

/// How an export failed, as the answer says it.
enum Failed {
    /// A bad parameter: 400.
    Request(String),
    /// Past a limit of `puppetry_limits::exports`: 413.
    TooLarge(String),
    /// The take or the stage: 422.
    Export(String),
}

impl Failed {
    fn text(&self) -> &str {
        match self {
            Failed::Request(t) | Failed::TooLarge(t) | Failed::Export(t) => t,
        }
    }
}

/// `GET /takes/NAME/export?format=glb&fps=30&size=1280x720&from=S&to=S`:
/// the route's steps in order (token, take, parameters, one export at a
/// time, a scratch folder, the export thread, the file streamed back), each
/// ending in its own HTTP status.
pub async fn export(
    State(shared): State<Arc<Shared>>,
    Path(name): Path<String>,
    Query(query): Query<HashMap<String, String>>,
    headers: HeaderMap,
) -> Response {
    let Ok(links) = shared.links() else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    if let Some(refused) = not_a_director(links, &headers) {
        return refused;
    }
    let Ok(take) = crate::takes::take_path(&links.takes_dir, &name) else {
        return plain(StatusCode::NOT_FOUND, "not found");
    };
    if !take.exists() {
        return plain(StatusCode::NOT_FOUND, &format!("no take {name}"));
    }
    let Parameters {
        download: Download {
            format,
            extension,
            mime,
        },
        fps,
        from,
        to,
        size: (width, height),
    } = match parameters(&query, &name) {
        Ok(p) => p,
        Err(problem) => return plain(StatusCode::BAD_REQUEST, &problem),
    };
    if links.exporting.swap(true, Ordering::AcqRel) {
        return plain(
            StatusCode::TOO_MANY_REQUESTS,
            "an export is running; try again when it ends",
        );
    }
    let scratch = match Scratch::new() {
        Ok(s) => s,
        Err(e) => {
            links.exporting.store(false, Ordering::Release);
            tracing::warn!("export of {name}: {e}");
            return plain(
                StatusCode::INTERNAL_SERVER_ERROR,
                "cannot make a folder for the export",
            );
        }
    };
    let out = scratch.path().join(format!("{name}.{extension}"));
    let export = ExportRequest {
        take,
        config: PathBuf::new(),
        format,
        fps,
        from,
        to,
        size: (width, height),
        output: out.clone(),
        // A fresh scratch folder: nothing there to replace.
        overwrite: puppetry_export::output::Overwrite::Never,
        // A damaged take is refused, naming the damage; the command
        // line's --salvage exports what is intact.
        salvage: false,
        audio: None,
    };
    let (done, finished) = tokio::sync::oneshot::channel();
    let runner = shared.clone();
    // The stage file with any puppets added since: the take may have them.
    let config = shared.lineup.borrow().config.clone();
    let label = name.clone();
    let takes_dir = links.takes_dir.clone();
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
                format: export.format.to_string(),
                shown: usize::MAX,
            };
            let result = run_export(&export, &config, &mut progress).map_err(|failed| {
                let text = without_folders(failed.text(), &takes_dir, Some(scratch.path()));
                match failed {
                    Failed::Request(_) => Failed::Request(text),
                    Failed::TooLarge(_) => Failed::TooLarge(text),
                    Failed::Export(_) => Failed::Export(text),
                }
            });
            links
                .export_state
                .send_replace(Published::of(ServerMessage::Export(ExportState {
                    take: label,
                    format: export.format.to_string(),
                    done: 1,
                    total: 1,
                    finished: true,
                    error: result.as_ref().err().map(|f| f.text().to_string()),
                })));
            links.exporting.store(false, Ordering::Release);
            // The folder goes with the answer (or here, if no one waits).
            let _ = done.send((result, scratch));
            crate::memory::give_back_freed();
        });
    if started.is_err() {
        links.exporting.store(false, Ordering::Release);
        return plain(StatusCode::INTERNAL_SERVER_ERROR, "cannot start an export");
    }
    match finished.await {
        Ok((Ok(()), scratch)) => {
            send_back(&out, scratch, mime, &format!("{name}.{extension}")).await
        }
        Ok((Err(failed), _)) => match failed {
            Failed::Request(t) => plain(StatusCode::BAD_REQUEST, &t),
            Failed::TooLarge(t) => plain(StatusCode::PAYLOAD_TOO_LARGE, &t),
            Failed::Export(t) => plain(StatusCode::UNPROCESSABLE_ENTITY, &t),
        },
        Err(_) => plain(StatusCode::INTERNAL_SERVER_ERROR, "the export stopped"),
    }
}

/// What an export request asks for.
struct Parameters {
    download: Download,
    fps: f64,
    from: Option<f64>,
    to: Option<f64>,
    size: (u32, u32),
}

/// The query's parameters, or what is wrong with them (a 400).
fn parameters(query: &HashMap<String, String>, name: &str) -> Result<Parameters, String> {
    if let Some(unknown) = query.keys().find(|k| !PARAMETERS.contains(&k.as_str())) {
        return Err(format!(
            "{unknown}: not a parameter (format, fps, size, from, to)"
        ));
    }
    let download = parse(query, name)?;
    check_numbers(query, download.format)?;
    let size = match query.get("size").map(|s| size(s)) {
        Some(s) => s?,
        None => (1280, 720),
    };
    let (Ok(fps), Ok(from), Ok(to)) = (
        number(query, "fps").unwrap_or(Ok(30.0)),
        number(query, "from").transpose(),
        number(query, "to").transpose(),
    ) else {
        return Err("fps, from and to must be numbers".into());
    };
    Ok(Parameters {
        download,
        fps,
        from,
        to,
        size,
    })
}

/// The finished export as the answer: opened, then its folder removed (the
/// file lives on while open), streamed from disk.
async fn send_back(
    out: &std::path::Path,
    scratch: Scratch,
    mime: &str,
    file_name: &str,
) -> Response {
    let file = tokio::fs::File::open(out).await;
    let length = match &file {
        Ok(f) => f.metadata().await.map(|m| m.len()).ok(),
        Err(_) => None,
    };
    let _ = tokio::task::spawn_blocking(move || drop(scratch)).await;
    let Ok(file) = file else {
        return plain(StatusCode::INTERNAL_SERVER_ERROR, "the export went missing");
    };
    let mut answer = attachment(Body::from_stream(read_stream(file)), mime, file_name);
    if let Some(length) = length {
        answer
            .headers_mut()
            .insert(header::CONTENT_LENGTH, HeaderValue::from(length));
    }
    answer
}

/// The export, after its cost is checked against the limits. A flag error
/// is the request's fault: a 400 naming the parameter.
fn run_export(
    export: &ExportRequest,
    config: &puppetry_stage::config::StageConfig,
    progress: &mut dyn puppetry_export::Progress,
) -> Result<(), Failed> {
    let flag = |flag: &str, problem: &str| {
        Failed::Request(format!("{}: {problem}", flag.trim_start_matches('-')))
    };
    let checked = puppetry_export::budget::check(export);
    match checked {
        Ok(_) => {}
        Err(e @ BudgetError::TooLarge { .. }) => return Err(Failed::TooLarge(e.to_string())),
        Err(BudgetError::Export(ExportError::Flag { flag: f, problem })) => {
            return Err(flag(&f, &problem));
        }
        Err(other) => return Err(Failed::Export(other.to_string())),
    }
    match export_take_with(export, config, progress) {
        Ok(_) => Ok(()),
        Err(TakeExportError::Export(ExportError::Flag { flag: f, problem })) => {
            Err(flag(&f, &problem))
        }
        Err(other) => Err(Failed::Export(other.to_string())),
    }
}

/// A format the page can download, with the file it comes as.
struct Download {
    format: Format,
    extension: &'static str,
    mime: &'static str,
}

fn parse(query: &HashMap<String, String>, name: &str) -> Result<Download, String> {
    let text = query
        .get("format")
        .map(String::as_str)
        .ok_or("format: required (glb, mp4, mov, webm or spine)")?;
    let format = text.parse::<Format>().ok();
    match format.and_then(|f| Some((f, f.download()?))) {
        Some((format, (extension, mime))) => Ok(Download {
            format,
            extension,
            mime,
        }),
        None => Err(format!(
            "format {text:?} of {name}: the page downloads glb, mp4, mov, webm or spine (png sequences: puppetry export)"
        )),
    }
}

/// The query's numbers, checked here so a bad one is a 400 naming the
/// parameter (the exporters name command-line flags).
fn check_numbers(query: &HashMap<String, String>, format: Format) -> Result<(), String> {
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
        // The exporter's own checks (its limits, H.264's even sizes).
        let checked = match puppetry_export::video::VideoFormat::of_format(format) {
            Some(video) => video.check_size(w, h),
            None => puppetry_export::raster::check_size(w, h),
        };
        if let Err(ExportError::Flag { problem, .. }) = checked {
            return Err(format!("size: {problem}"));
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
        self.links
            .export_state
            .send_replace(Published::of(ServerMessage::Export(ExportState {
                take: self.take.clone(),
                format: self.format.clone(),
                done,
                total,
                finished: false,
                error: None,
            })));
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
