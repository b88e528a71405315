//! The network edge: one port for HTTP and WebSocket, routed by axum and
//! served by hyper from the edge's own accept loop ([`serve`]). It owns
//! what a stranger can reach before any token is checked: the routes (the
//! web client's files, puppet pictures, the WebSocket upgrade), the
//! WebSocket's Origin check (made by `origin`: against the daemon's own
//! addresses, never the request's `Host`), the caps on open connections (in all, per address,
//! and WebSockets per address: past them a 503, or a close `1013`), the
//! time a connection may take to send its request head
//! (`puppetry_limits::net`), request size limits, MIME types and 404s.
//! Accept errors (a full file table, say) back off instead of spinning.

use std::collections::HashMap;
use std::net::IpAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, Extension, Path, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use include_dir::{Dir, include_dir};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tower::ServiceExt;
use tower_http::limit::RequestBodyLimitLayer;
use tower_http::services::ServeDir;

use super::origin::{LocalAddr, PeerAddr, own_origin};
use super::{MAX_CLIENT_MESSAGE, READ_BUFFER, Shared, websocket};

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

/// How long the edge waits on its connections; the defaults are
/// `puppetry_limits::net`'s, tests shorten them (`serve::Options::edge`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeTimes {
    /// A request head must arrive within this (silent, idle and trickling
    /// connections are closed after it).
    pub header_read: Duration,
    /// Every WebSocket is pinged this often; one that has not answered the
    /// last ping by the next is closed.
    pub ping_every: Duration,
}

impl Default for EdgeTimes {
    fn default() -> EdgeTimes {
        EdgeTimes {
            header_read: puppetry_limits::net::HEADER_READ_TIMEOUT,
            ping_every: puppetry_limits::net::WEBSOCKET_PING_EVERY,
        }
    }
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
                .route(crate::protocol::upload::PATH, post(super::uploads::add))
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
    Extension(LocalAddr(local)): Extension<LocalAddr>,
    Extension(times): Extension<EdgeTimes>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    if let Some(origin) = headers.get(header::ORIGIN) {
        let allowed = shared.admission().allowed_origins;
        if !own_origin(origin.to_str().unwrap_or(""), local, &allowed) {
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
                    super::close::TRY_AGAIN_LATER,
                    "too many connections from this address",
                )
                .await;
                return;
            };
            if let Err(e) = websocket(socket, shared, peer.ip(), place, times).await {
                tracing::debug!("websocket ended: {e}");
            }
        })
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
    if let super::Backend::Upstream(link) = &shared.backend {
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
    let read = {
        let picture = picture.clone();
        tokio::task::spawn_blocking(move || picture.png()).await
    };
    let read = match read {
        Ok(read) => read,
        Err(e) => {
            tracing::warn!("{picture}: {e}");
            return not_found();
        }
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

/// Serves `app` on `listener` until `shutdown` resolves, then lets each
/// connection finish its request and waits for them (upgraded WebSockets
/// are the stage's to close). Each connection holds a place under the cap
/// on open connections and under its address's cap (its WebSockets' cap
/// and [`HTTP_PER_ADDRESS`](puppetry_limits::net::HTTP_PER_ADDRESS) more);
/// past either it is answered 503 and closed at once, so a flood cannot
/// hold the daemon's memory or file table. hyper serves HTTP/1 with a
/// timer, so its header-read timeout runs: a connection that sends no
/// request head in time (silent, idle after an answer, or trickling one
/// header line at a time) is closed.
pub(super) async fn serve(
    listener: TcpListener,
    shared: Arc<Shared>,
    times: EdgeTimes,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) {
    let app = router(shared.clone()).layer(axum::Extension(times));
    let open = Arc::new(Semaphore::new(shared.max_connections));
    let places = Places::default();
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(times.header_read);
    // Each connection task holds a sender; when the last is gone, every
    // connection has ended.
    let (alive, mut all_ended) = tokio::sync::mpsc::channel::<()>(1);
    let (stop, stopping) = tokio::sync::watch::channel(false);
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    backoff(&e).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        let _ = stream.set_nodelay(true);
        let Ok(place) = open.clone().try_acquire_owned() else {
            tracing::debug!(%peer, "connection refused: too many open connections");
            tokio::spawn(refuse(stream, "too many open connections"));
            continue;
        };
        let cap = shared
            .admission()
            .max_per_address
            .saturating_add(puppetry_limits::net::HTTP_PER_ADDRESS);
        let Some(address) = places.take(peer.ip(), cap) else {
            shared.log.warn(&peer.ip().to_string(), || {
                format!("connection refused: {cap} open from this address already")
            });
            tokio::spawn(refuse(stream, "too many connections from this address"));
            continue;
        };
        let local = LocalAddr(stream.local_addr().ok());
        let io = hyper_util::rt::TokioIo::new(CappedStream {
            stream,
            _place: place,
            _address: address,
        });
        let app = app.clone();
        let service = hyper::service::service_fn(
            move |mut request: axum::extract::Request<hyper::body::Incoming>| {
                let extensions = request.extensions_mut();
                extensions.insert(ConnectInfo(PeerAddr(peer)));
                extensions.insert(local);
                app.clone().oneshot(request)
            },
        );
        let connection = http.serve_connection(io, service).with_upgrades();
        let mut stopping = stopping.clone();
        let alive = alive.clone();
        tokio::spawn(async move {
            let mut connection = std::pin::pin!(connection);
            tokio::select! {
                served = connection.as_mut() => {
                    if let Err(e) = served {
                        tracing::debug!(%peer, "connection ended: {e}");
                    }
                }
                // Set once, at shutdown (or the loop is gone).
                _ = stopping.changed() => {
                    connection.as_mut().graceful_shutdown();
                    let _ = connection.await;
                }
            }
            drop(alive);
        });
    }
    drop(listener);
    let _ = stop.send(true);
    drop(alive);
    let _ = all_ended.recv().await;
}

/// After an accept error: errors of one connection (reset before it was
/// accepted) are nothing to wait for; others (a full file table) are
/// waited out a moment instead of spinning.
async fn backoff(error: &std::io::Error) {
    use std::io::ErrorKind as K;
    if matches!(
        error.kind(),
        K::ConnectionRefused | K::ConnectionAborted | K::ConnectionReset
    ) {
        return;
    }
    tracing::error!("accepting a connection: {error}");
    tokio::time::sleep(Duration::from_secs(1)).await;
}

/// Open connections (HTTP and WebSocket) per client address.
#[derive(Default, Clone)]
struct Places {
    open: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

impl Places {
    /// A place for `ip`, or `None` if it holds `cap` already.
    fn take(&self, ip: IpAddr, cap: usize) -> Option<Place> {
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        let count = open.entry(ip).or_insert(0);
        if *count >= cap {
            return None;
        }
        *count += 1;
        Some(Place {
            places: self.clone(),
            ip,
        })
    }
}

/// A connection's place under its address's cap, given back when the
/// connection (or the WebSocket it became) is dropped.
struct Place {
    places: Places,
    ip: IpAddr,
}

impl Drop for Place {
    fn drop(&mut self) {
        let mut open = self.places.open.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(count) = open.get_mut(&self.ip) {
            *count -= 1;
            if *count == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// A connection holding its places under the caps until it closes.
pub struct CappedStream {
    stream: TcpStream,
    _place: OwnedSemaphorePermit,
    _address: Place,
}

async fn refuse(mut stream: TcpStream, why: &str) {
    let answer = format!(
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\n\
         Content-Length: {}\r\nConnection: close\r\nRetry-After: 1\r\n\r\n{why}",
        why.len()
    );
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        stream.write_all(answer.as_bytes()).await?;
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
