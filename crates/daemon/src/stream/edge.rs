//! The network edge: one port for HTTP and WebSocket, served by axum. It
//! owns what a stranger can reach before any token is checked: the routes
//! (the web client's files, puppet pictures, the WebSocket upgrade), the
//! WebSocket's Origin check, the cap on open connections (past it a
//! connection gets a 503 and is closed) and on WebSockets per address,
//! request size limits, MIME types and 404s. Accept errors (a full
//! file table, say) back off inside axum's own accept loop instead of
//! spinning.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;

use axum::Router;
use axum::body::Body;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use include_dir::{Dir, include_dir};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tower_http::limit::RequestBodyLimitLayer;
use tower_http::services::ServeDir;

use super::{MAX_CLIENT_MESSAGE, READ_BUFFER, Shared, websocket};
use puppetry_stage::Picture;

/// The web client, compiled in.
static WEB_CLIENT: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/../../clients/web");

/// Largest request body taken (the daemon takes no bodies: GET only).
const MAX_BODY: usize = 16 * 1024;

/// Where the web client's files come from.
#[derive(Debug, Clone, Default)]
pub enum WebFiles {
    /// The copy compiled into the daemon.
    #[default]
    Embedded,
    /// A folder, for client development (`serve --web-root`).
    Folder(PathBuf),
}

/// The routes of the daemon's one port.
pub fn router(shared: Arc<Shared>) -> Router {
    let files = match &shared.web_files {
        WebFiles::Embedded => Router::new()
            .route("/", get(|| async { embedded("index.html") }))
            .route("/{*path}", get(embedded_path)),
        WebFiles::Folder(dir) => Router::new().fallback_service(ServeDir::new(dir)),
    };
    Router::new()
        .route("/ws", get(upgrade))
        .route("/puppets/{id}/texture.png", get(texture))
        .route("/takes/{file}", get(super::exports::take_file))
        .route("/takes/{name}/export", get(super::exports::export))
        .with_state(shared.clone())
        .merge(files)
        .layer(RequestBodyLimitLayer::new(MAX_BODY))
        // Pictures are larger than any other request: the upload reads its
        // body against its own limit and answers JSON past it.
        .merge(
            Router::new()
                .route("/puppets", post(super::uploads::add))
                .with_state(shared),
        )
}

/// The WebSocket upgrade. A page from a foreign origin is refused (403)
/// before anything else, so a site a performer happens to visit cannot
/// drive the stage with their token (cross-site WebSocket hijacking); past
/// the per-address cap the socket is opened only to be closed with 1013
/// and a reason a page can show.
async fn upgrade(
    State(shared): State<Arc<Shared>>,
    ConnectInfo(PeerAddr(peer)): ConnectInfo<PeerAddr>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    if let Some(origin) = headers.get(header::ORIGIN) {
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        let allowed = shared.admission().allowed_origins;
        if !origin_allowed(origin.to_str().unwrap_or(""), host, &allowed) {
            shared.log.warn(&peer.ip().to_string(), || {
                format!(
                    "WebSocket from origin {:?} refused (not the daemon's own nor in access.allowed_origins)",
                    super::guard::clip(&String::from_utf8_lossy(origin.as_bytes()), 200)
                )
            });
            return (
                StatusCode::FORBIDDEN,
                "this origin may not open the stage's WebSocket (see access.allowed_origins)\n",
            )
                .into_response();
        }
    }
    let place = AddressPlace::take(&shared, peer.ip());
    // tungstenite zero-fills its whole read buffer before every read
    // attempt; clients send small messages, so a small buffer saves a
    // 128 KiB memset per wake-up of every connection. Nothing is kept
    // back for batching: each send goes out whole (frames are big).
    upgrade
        .max_message_size(MAX_CLIENT_MESSAGE)
        .max_frame_size(MAX_CLIENT_MESSAGE)
        .read_buffer_size(READ_BUFFER)
        .write_buffer_size(0)
        .on_upgrade(move |mut socket| async move {
            let Some(place) = place else {
                tracing::debug!(%peer, "WebSocket refused: too many from this address");
                super::close_with(
                    &mut socket,
                    super::close::TRY_LATER,
                    "too many connections from this address",
                )
                .await;
                return;
            };
            if let Err(e) = websocket(socket, shared, peer.ip(), place).await {
                tracing::debug!("websocket ended: {e}");
            }
        })
}

/// Whether a page of `origin` may open the WebSocket: its own page (the
/// origin's host and port are the request's `Host`), or one listed.
pub(super) fn origin_allowed(origin: &str, host: Option<&str>, allowed: &[String]) -> bool {
    let origin = origin.trim_end_matches('/');
    if allowed
        .iter()
        .any(|a| a.trim_end_matches('/').eq_ignore_ascii_case(origin))
    {
        return true;
    }
    let authority = origin.split_once("://").map(|(_, rest)| rest).unwrap_or("");
    match host {
        Some(host) => !authority.is_empty() && authority.eq_ignore_ascii_case(host),
        None => false,
    }
}

/// The client's address, as axum's `ConnectInfo` carries it for the
/// capped listener.
#[derive(Debug, Clone, Copy)]
pub struct PeerAddr(pub SocketAddr);

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, CappedListener>>
    for PeerAddr
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, CappedListener>) -> PeerAddr {
        PeerAddr(*stream.remote_addr())
    }
}

/// A WebSocket's place under its address's cap, given back when dropped.
pub struct AddressPlace {
    shared: Arc<Shared>,
    ip: IpAddr,
}

impl AddressPlace {
    /// A place for `ip`, or `None` if it has `max_per_address` already.
    fn take(shared: &Arc<Shared>, ip: IpAddr) -> Option<AddressPlace> {
        let cap = shared.admission().max_per_address;
        let mut open = shared.addresses.lock().unwrap_or_else(|p| p.into_inner());
        let count = open.entry(ip).or_insert(0);
        if *count >= cap {
            return None;
        }
        *count += 1;
        Some(AddressPlace {
            shared: shared.clone(),
            ip,
        })
    }
}

impl Drop for AddressPlace {
    fn drop(&mut self) {
        let mut open = self
            .shared
            .addresses
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        if let Some(count) = open.get_mut(&self.ip) {
            *count -= 1;
            if *count == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

async fn texture(State(shared): State<Arc<Shared>>, Path(id): Path<String>) -> Response {
    if let super::Backend::Relay(link) = &shared.backend {
        let picture = match id.parse::<u32>() {
            Ok(id) => link.picture(id).await,
            Err(_) => None,
        };
        return match picture {
            Some(bytes) => with_type(Body::from(bytes), "image/png"),
            None => not_found(),
        };
    }
    let path = id.parse::<usize>().ok().and_then(|i| {
        let lineup = shared.lineup.borrow();
        lineup.description.images.get(i).cloned()
    });
    let Some(picture) = path else {
        return not_found();
    };
    let read = match &picture {
        Picture::File(path) => tokio::fs::read(path).await,
        stroke => stroke.png(),
    };
    match read {
        Ok(bytes) => with_type(Body::from(bytes), "image/png"),
        Err(e) => {
            tracing::warn!("{picture}: {e}");
            not_found()
        }
    }
}

async fn embedded_path(Path(path): Path<String>) -> Response {
    embedded(&path)
}

/// A file of the compiled-in web client. The path is already
/// percent-decoded; anything that could climb out is simply not found
/// (there is no file system beneath to climb into, but say so plainly).
fn embedded(path: &str) -> Response {
    if path.split('/').any(|part| part == ".." || part == ".") || path.contains('\\') {
        return not_found();
    }
    match WEB_CLIENT.get_file(path) {
        Some(file) => {
            let mime = mime_guess::from_path(path).first_or_octet_stream();
            with_type(Body::from(file.contents()), mime.as_ref())
        }
        None => not_found(),
    }
}

fn with_type(body: Body, mime: &str) -> Response {
    let mut response = body.into_response();
    if let Ok(value) = HeaderValue::from_str(mime) {
        response.headers_mut().insert(header::CONTENT_TYPE, value);
    }
    response
}

fn not_found() -> Response {
    (StatusCode::NOT_FOUND, "not found\n").into_response()
}

/// The listener with a cap on open connections. A connection past the cap
/// is answered `503` and closed at once, so a flood cannot hold the
/// daemon's memory or file table; the others are served as usual.
pub struct CappedListener {
    listener: TcpListener,
    open: Arc<Semaphore>,
}

impl CappedListener {
    pub fn new(listener: TcpListener, max_connections: usize) -> CappedListener {
        CappedListener {
            listener,
            open: Arc::new(Semaphore::new(max_connections)),
        }
    }
}

/// A connection holding its place under the cap until it closes.
pub struct CappedStream {
    stream: TcpStream,
    _place: OwnedSemaphorePermit,
}

impl axum::serve::Listener for CappedListener {
    type Io = CappedStream;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        loop {
            // axum's accept backs off on errors such as a full file table.
            let (stream, peer) = axum::serve::Listener::accept(&mut self.listener).await;
            let _ = stream.set_nodelay(true);
            match self.open.clone().try_acquire_owned() {
                Ok(place) => {
                    return (
                        CappedStream {
                            stream,
                            _place: place,
                        },
                        peer,
                    );
                }
                Err(_) => {
                    tracing::debug!(%peer, "connection refused: too many open connections");
                    tokio::spawn(refuse(stream));
                }
            }
        }
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        self.listener.local_addr()
    }
}

async fn refuse(mut stream: TcpStream) {
    let answer = b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\n\
        Content-Length: 26\r\nConnection: close\r\nRetry-After: 1\r\n\r\n\
        too many open connections";
    let _ = tokio::time::timeout(std::time::Duration::from_secs(2), async {
        stream.write_all(answer).await?;
        stream.shutdown().await
    })
    .await;
}

impl tokio::io::AsyncRead for CappedStream {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl tokio::io::AsyncWrite for CappedStream {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.stream).poll_write(cx, buf)
    }
    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }
    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.stream).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::origin_allowed;

    #[test]
    fn only_the_daemons_own_or_listed_origins_pass() {
        let listed = vec!["https://show.example".to_string()];
        let host = Some("127.0.0.1:8080");
        assert!(origin_allowed("http://127.0.0.1:8080", host, &[]));
        assert!(origin_allowed("https://show.example", host, &listed));
        assert!(origin_allowed("https://SHOW.example/", host, &listed));
        for foreign in [
            "https://evil.example",
            "http://127.0.0.1:8081",
            "http://127.0.0.1:8080.evil.example",
            "null",
            "",
        ] {
            assert!(!origin_allowed(foreign, host, &listed), "{foreign}");
        }
        assert!(!origin_allowed("http://127.0.0.1:8080", None, &[]));
    }
}
