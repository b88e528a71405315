//! Who a request comes from, and whether the page that opened it is the
//! daemon's own: the client's and the daemon's addresses as the accept
//! loop records them on every request, and the Origin check the WebSocket
//! upgrade and uploads share (against the daemon's own addresses and the
//! stage file's `allowed_origins`, never the request's `Host`).

use std::net::{IpAddr, SocketAddr};

/// The address a connection reached the daemon at: its own origin, as
/// far as the Origin check goes.
#[derive(Debug, Clone, Copy)]
pub struct LocalAddr(pub Option<SocketAddr>);

/// Whether a page of `origin` may open the WebSocket: one listed in
/// `access.allowed_origins`, or the daemon's own page — served from the
/// address and port the connection reached (`local`), under that address,
/// `localhost` (on loopback) or this machine's host name. The request's
/// `Host` is the page's to say, so it decides nothing: a page of a
/// rebound name (DNS rebinding) names its own host there.
pub fn own_origin(origin: &str, local: Option<SocketAddr>, allowed: &[String]) -> bool {
    if listed(origin, allowed) {
        return true;
    }
    let (Some(local), Some((host, port))) = (local, host_and_port(origin)) else {
        return false;
    };
    if port != local.port() {
        return false;
    }
    let literal = host.trim_start_matches('[').trim_end_matches(']');
    if literal.parse::<IpAddr>().is_ok_and(|ip| ip == local.ip()) {
        return true;
    }
    (local.ip().is_loopback() && host == "localhost") || own_host_names().contains(&host)
}

/// `origin` is one of `allowed` (case and a trailing `/` aside).
fn listed(origin: &str, allowed: &[String]) -> bool {
    let origin = origin.trim_end_matches('/');
    allowed
        .iter()
        .any(|a| a.trim_end_matches('/').eq_ignore_ascii_case(origin))
}

/// An `http(s)://host[:port]` origin's host (lowercase; an IPv6 literal in
/// its brackets) and port (the scheme's default if none is given).
fn host_and_port(origin: &str) -> Option<(String, u16)> {
    let (scheme, authority) = origin.trim_end_matches('/').split_once("://")?;
    let default_port = match scheme.to_ascii_lowercase().as_str() {
        "http" => 80,
        "https" => 443,
        _ => return None,
    };
    if authority.is_empty() || authority.contains(['/', '@', '?', '#']) {
        return None;
    }
    let (host, port) = match authority.rsplit_once(':') {
        Some((host, port)) if !port.contains(']') => (host, port.parse::<u16>().ok()?),
        _ => (authority, default_port),
    };
    (!host.is_empty()).then(|| (host.to_ascii_lowercase(), port))
}

/// This machine's host name, and with `.local` (mDNS), lowercased: a page
/// served as `http://<host name>:<port>/` is the daemon's own.
fn own_host_names() -> &'static [String] {
    static NAMES: std::sync::OnceLock<Vec<String>> = std::sync::OnceLock::new();
    NAMES.get_or_init(|| {
        let mut buffer = [0u8; 256];
        // SAFETY: the buffer is valid for its length; gethostname writes
        // at most that many bytes.
        let read = unsafe { libc::gethostname(buffer.as_mut_ptr().cast(), buffer.len()) };
        if read != 0 {
            return Vec::new();
        }
        let end = buffer.iter().position(|&b| b == 0).unwrap_or(buffer.len());
        let name = String::from_utf8_lossy(&buffer[..end]).to_ascii_lowercase();
        if name.is_empty() {
            return Vec::new();
        }
        let local = format!("{}.local", name.trim_end_matches(".local"));
        vec![name, local]
    })
}

/// The client's address, as axum's `ConnectInfo` carries it (the accept
/// loop puts it on every request).
#[derive(Debug, Clone, Copy)]
pub struct PeerAddr(pub SocketAddr);

#[cfg(test)]
mod tests {
    use super::own_origin;

    #[test]
    fn only_the_daemons_own_or_listed_origins_pass() {
        let listed = vec!["https://show.example".to_string()];
        let local = Some("127.0.0.1:8080".parse().unwrap());
        assert!(own_origin("http://127.0.0.1:8080", local, &[]));
        assert!(own_origin("https://show.example", local, &listed));
        assert!(own_origin("https://SHOW.example/", local, &listed));
        for foreign in [
            "https://evil.example",
            "http://127.0.0.1:8081",
            "http://127.0.0.1:8080.evil.example",
            "null",
            "",
        ] {
            assert!(!own_origin(foreign, local, &listed), "{foreign}");
        }
        assert!(!own_origin("http://127.0.0.1:8080", None, &[]));
    }

    #[test]
    fn a_rebound_name_is_not_the_daemons_own_though_host_says_so() {
        // DNS rebinding: the attacker's name resolves to the daemon, so
        // the page's Origin and Host agree — and name the attacker.
        let rebound = "http://evil.example:8080";
        let local = Some("127.0.0.1:8080".parse().unwrap());
        assert!(!own_origin(rebound, local, &[]));
        assert!(!own_origin("http://evil.example", local, &[]));
        // The daemon's own page, under its address or localhost.
        for own in [
            "http://127.0.0.1:8080",
            "http://localhost:8080",
            "http://LOCALHOST:8080/",
        ] {
            assert!(own_origin(own, local, &[]), "{own}");
        }
        // Another port, another address, another scheme: not its own.
        for foreign in [
            "http://127.0.0.1:8081",
            "http://127.0.0.2:8080",
            "ftp://127.0.0.1:8080",
            "http://127.0.0.1:8080@evil.example",
            "null",
        ] {
            assert!(!own_origin(foreign, local, &[]), "{foreign}");
        }
        // localhost is only loopback's name; a LAN address is its own.
        let lan = Some("192.168.1.5:8080".parse().unwrap());
        assert!(!own_origin("http://localhost:8080", lan, &[]));
        assert!(own_origin("http://192.168.1.5:8080", lan, &[]));
        let v6 = Some("[::1]:80".parse().unwrap());
        assert!(own_origin("http://[::1]", v6, &[]));
        // Listed origins pass wherever the page came from.
        let listed = vec!["https://show.example".to_string()];
        assert!(own_origin("https://show.example/", local, &listed));
        assert!(!own_origin("http://127.0.0.1:8080", None, &[]));
    }
}
