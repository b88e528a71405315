//! The stage file's `listen` takes what `serve --listen` takes: an address,
//! a host name and port, or a bare port (on 127.0.0.1); anything else is
//! refused naming the field's line.

use std::net::SocketAddr;
use std::path::Path;

use puppetry_stage::config::StageConfig;

fn listen(value: &str) -> Result<SocketAddr, String> {
    let text = format!("[stage]\nwidth = 100\nheight = 100\nlisten = \"{value}\"\n");
    StageConfig::parse("listen.toml", &text, Path::new("/"))
        .map(|c| c.stage.listen)
        .map_err(|e| e.to_string())
}

#[test]
fn listen_takes_an_address_a_host_name_or_a_bare_port() {
    assert_eq!(
        listen("0.0.0.0:8185").unwrap(),
        "0.0.0.0:8185".parse().unwrap()
    );
    assert_eq!(listen("8185").unwrap(), "127.0.0.1:8185".parse().unwrap());
    let local = listen("localhost:8185").unwrap();
    assert!(local.ip().is_loopback() && local.port() == 8185, "{local}");
    let error = listen("localhost:port").unwrap_err();
    assert!(
        error.contains("listen.toml") && error.contains("line 4") && error.contains("not a port"),
        "{error}"
    );
}
