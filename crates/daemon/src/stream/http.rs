//! The little HTTP the daemon needs: read a request head, hand the
//! connection (with the bytes already read) to the WebSocket handshake, or
//! answer a GET for a file of the web client or a puppet's picture.

use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::TcpStream;

use super::Shared;

/// Largest request head accepted.
const MAX_HEAD: usize = 16 * 1024;

#[derive(Debug)]
pub struct Request {
    pub method: String,
    pub path: String,
    headers: Vec<(String, String)>,
}

impl Request {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    pub fn wants_websocket(&self) -> bool {
        self.header("upgrade")
            .is_some_and(|v| v.eq_ignore_ascii_case("websocket"))
    }
}

/// A connection whose first bytes were already read: they are replayed
/// before the rest, so the WebSocket handshake sees the whole request.
pub struct Prefixed {
    head: Vec<u8>,
    offset: usize,
    stream: TcpStream,
}

impl AsyncRead for Prefixed {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        if self.offset < self.head.len() {
            let n = (self.head.len() - self.offset).min(buf.remaining());
            let start = self.offset;
            buf.put_slice(&self.head[start..start + n]);
            self.offset += n;
            return Poll::Ready(Ok(()));
        }
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for Prefixed {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

fn bad(message: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, message.to_string())
}

/// Reads one request head (within `timeout`) and returns it with the
/// connection, the head kept for replay.
pub async fn read_request(
    mut stream: TcpStream,
    timeout: Duration,
) -> std::io::Result<(Request, Prefixed)> {
    let mut head = Vec::with_capacity(1024);
    let read = async {
        let mut chunk = [0u8; 1024];
        loop {
            if head.windows(4).any(|w| w == b"\r\n\r\n") {
                return Ok(());
            }
            if head.len() > MAX_HEAD {
                return Err(bad("request head too large"));
            }
            let n = stream.read(&mut chunk).await?;
            if n == 0 {
                return Err(bad("connection closed before the request ended"));
            }
            head.extend_from_slice(&chunk[..n]);
        }
    };
    tokio::time::timeout(timeout, read).await.map_err(|_| {
        std::io::Error::new(std::io::ErrorKind::TimedOut, "request head timed out")
    })??;
    let end = head
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or(head.len());
    let text = std::str::from_utf8(&head[..end]).map_err(|_| bad("request head is not UTF-8"))?;
    let mut lines = text.split("\r\n");
    let mut first = lines.next().unwrap_or_default().split(' ');
    let method = first.next().unwrap_or_default().to_string();
    let path = first.next().unwrap_or_default().to_string();
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let request = Request {
        method,
        path,
        headers,
    };
    Ok((
        request,
        Prefixed {
            head,
            offset: 0,
            stream,
        },
    ))
}

fn content_type(path: &str) -> &'static str {
    match path.rsplit('.').next() {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("png") => "image/png",
        Some("json") => "application/json",
        _ => "application/octet-stream",
    }
}

/// Answers a plain GET: the web client's files and the puppets' pictures.
pub async fn serve_file(
    mut stream: Prefixed,
    request: &Request,
    shared: &Shared,
) -> std::io::Result<()> {
    let path = request.path.split('?').next().unwrap_or_default();
    let file = if request.method != "GET" {
        None
    } else if path == "/" {
        Some(shared.web_root.join("index.html"))
    } else if let Some(rest) = path.strip_prefix("/puppets/") {
        rest.strip_suffix("/texture.png")
            .and_then(|id| id.parse::<usize>().ok())
            .and_then(|id| shared.stage.images.get(id).cloned())
    } else {
        // Only plain file names of the web client: no traversal.
        let name = &path[1..];
        let plain = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'))
            && !name.starts_with('.');
        plain.then(|| shared.web_root.join(name))
    };
    let body = match file {
        Some(file) => tokio::fs::read(&file)
            .await
            .ok()
            .map(|b| (b, content_type(&file.to_string_lossy()))),
        None => None,
    };
    let response = match body {
        Some((bytes, kind)) => {
            let mut r = format!(
                "HTTP/1.1 200 OK\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n",
                bytes.len()
            )
            .into_bytes();
            r.extend_from_slice(&bytes);
            r
        }
        None => {
            b"HTTP/1.1 404 Not Found\r\nContent-Length: 10\r\nConnection: close\r\n\r\nnot found\n"
                .to_vec()
        }
    };
    stream.write_all(&response).await?;
    stream.shutdown().await
}
