//! Connecting to NATS as one party of a stage, and the nats-server
//! configuration that keeps each party to its own subjects.
//!
//! NATS is where the relay tier can be attacked: whoever can publish on a
//! stage's subjects speaks for the daemon to every relay's viewers, or for
//! a relay's performers to the daemon. So nats-server runs with a user
//! per party ([`server_config`]): the daemon alone publishes `out.>` and
//! reads `in.>`; a relay publishes only `in.<its name>.>` and reads only
//! `out.>` and its own inbox `reply.<its name>.>`. A party's credentials
//! are in its NATS address, `nats://user:password@host:port`, or the
//! password is left out of it (and out of `ps`, and of a stage file in a
//! repository) and given in the environment as `PUPPETRY_NATS_PASSWORD`.
//! Addresses are shown (logs, errors) without their password.

use std::time::Duration;

use super::{ANSWER_WITHIN, RelayError, Subjects, is_name};

/// Where a password left out of a NATS address is read from.
pub(crate) const PASSWORD_VARIABLE: &str = "PUPPETRY_NATS_PASSWORD";

/// The daemon's user in [`server_config`] (a relay may not be named so).
pub const DAEMON_USER: &str = "puppetry";

/// A NATS address taken apart: where, and as whom.
#[derive(Clone)]
pub struct NatsAddress {
    /// The servers, comma-separated, without credentials.
    servers: String,
    user: Option<String>,
    password: Option<String>,
}

impl std::fmt::Debug for NatsAddress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.shown())
    }
}

impl NatsAddress {
    /// `nats://[user[:password]@]host:port`, or several of them
    /// comma-separated (the servers of one cluster, all as one user). A
    /// user without a password takes the one in the environment variable
    /// `PUPPETRY_NATS_PASSWORD`.
    pub fn parse(text: &str) -> Result<NatsAddress, RelayError> {
        Self::parse_with(text, std::env::var(PASSWORD_VARIABLE).ok())
    }

    fn parse_with(text: &str, from_environment: Option<String>) -> Result<NatsAddress, RelayError> {
        let mut servers = Vec::new();
        let mut credentials: Option<(String, Option<String>)> = None;
        for server in text.split(',').map(str::trim) {
            let (address, given) = split_credentials(server);
            let bad = |problem: String| RelayError::Address {
                url: address.clone(),
                problem,
            };
            address
                .parse::<async_nats::ServerAddr>()
                .map_err(|e| bad(e.to_string()))?;
            if let Some(given) = given {
                if credentials.as_ref().is_some_and(|c| *c != given) {
                    return Err(bad(
                        "every server of one address is given as one user".into()
                    ));
                }
                credentials = Some(given);
            }
            servers.push(address);
        }
        let (user, password) = match credentials {
            Some((user, password)) => (Some(user), password.or(from_environment)),
            None => (None, None),
        };
        if user.as_deref() == Some("") {
            return Err(RelayError::Address {
                url: servers.join(","),
                problem: "an empty user name".into(),
            });
        }
        Ok(NatsAddress {
            servers: servers.join(","),
            user,
            password,
        })
    }

    /// The address as logs and errors show it: the user, never the password.
    pub(crate) fn shown(&self) -> String {
        match &self.user {
            None => self.servers.clone(),
            Some(user) => self
                .servers
                .split(',')
                .map(|s| match s.split_once("://") {
                    Some((scheme, rest)) => format!("{scheme}://{user}@{rest}"),
                    None => format!("{user}@{s}"),
                })
                .collect::<Vec<_>>()
                .join(","),
        }
    }

    /// The user the address names, if any.
    pub fn user(&self) -> Option<&str> {
        self.user.as_deref()
    }

    /// Connects (or keeps trying: the client retries while the server is
    /// away) as this address's user.
    pub(crate) async fn connect(
        &self,
        options: async_nats::ConnectOptions,
    ) -> Result<async_nats::Client, RelayError> {
        let options = match (&self.user, &self.password) {
            (Some(user), password) => {
                options.user_and_password(user.clone(), password.clone().unwrap_or_default())
            }
            (None, _) => options,
        };
        options
            .connect(self.servers.as_str())
            .await
            .map_err(|e| RelayError::Connect {
                url: self.shown(),
                problem: e.to_string(),
            })
    }
}

/// `(address without credentials, (user, password))` of one server URL.
fn split_credentials(server: &str) -> (String, Option<(String, Option<String>)>) {
    let (scheme, rest) = match server.split_once("://") {
        Some((scheme, rest)) => (Some(scheme), rest),
        None => (None, server),
    };
    let authority_end = rest.find(['/', '?', '#']).unwrap_or(rest.len());
    let (authority, path) = rest.split_at(authority_end);
    let Some((userinfo, host)) = authority.rsplit_once('@') else {
        return (server.to_string(), None);
    };
    let (user, password) = match userinfo.split_once(':') {
        Some((user, password)) => (user, Some(decoded(password))),
        None => (userinfo, None),
    };
    let address = match scheme {
        Some(scheme) => format!("{scheme}://{host}{path}"),
        None => format!("{host}{path}"),
    };
    (address, Some((decoded(user), password)))
}

/// A URL's userinfo part percent-decoded (a password may hold `@` or `:`).
fn decoded(part: &str) -> String {
    percent_encoding::percent_decode_str(part)
        .decode_utf8_lossy()
        .into_owned()
}

/// NATS connection settings both sides use: start whether or not the
/// server is up, retry for ever, quickly (a show is on), and never wait
/// long for an answer. The server's refusals (a permission it does not
/// grant, credentials it does not know) are logged as warnings: a relay
/// named otherwise than its NATS user hears nothing but these.
pub(crate) fn connect_options(
    name: &str,
    up: tokio::sync::watch::Sender<bool>,
) -> async_nats::ConnectOptions {
    async_nats::ConnectOptions::new()
        .name(name)
        .retry_on_initial_connect()
        .max_reconnects(None)
        .reconnect_delay_callback(|attempt| {
            Duration::from_millis((50u64 << attempt.min(3)).min(250))
        })
        .request_timeout(Some(ANSWER_WITHIN))
        .event_callback(move |event| {
            let up = up.clone();
            async move {
                match event {
                    async_nats::Event::Connected => {
                        up.send_replace(true);
                    }
                    async_nats::Event::Disconnected | async_nats::Event::Closed => {
                        up.send_replace(false);
                    }
                    async_nats::Event::ServerError(e) => tracing::warn!("NATS server: {e}"),
                    other => tracing::debug!("NATS: {other}"),
                }
            }
        })
}

/// Once connected, warns if the server lets anyone in: then anyone who
/// reaches it can speak for the daemon or for any relay.
pub(crate) async fn warn_if_open(
    client: async_nats::Client,
    mut up: tokio::sync::watch::Receiver<bool>,
) {
    if up.wait_for(|up| *up).await.is_ok() && !client.server_info().auth_required {
        tracing::warn!(
            "the NATS server asks for no credentials: anyone who reaches it can act as the \
             daemon or a relay; run it with users and permissions (docs/scaling.md)"
        );
    }
}

/// A password as a nats-server configuration gives it.
#[derive(Debug, Clone)]
pub enum Secret {
    /// Written into the file (one made for a run, such as `soak`'s).
    Literal(String),
    /// Read from this environment variable when nats-server starts (a file
    /// kept in a repository); nats-server refuses to start without it.
    Environment(String),
}

impl Secret {
    fn written(&self) -> Result<String, RelayError> {
        match self {
            Secret::Literal(text) => {
                if text.is_empty()
                    || text
                        .chars()
                        .any(|c| c == '"' || c == '\\' || c.is_control())
                {
                    return Err(RelayError::ServerConfig(
                        "a password is empty or holds a quote, a backslash or a control character"
                            .into(),
                    ));
                }
                Ok(format!("\"{text}\""))
            }
            Secret::Environment(name) => {
                if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                    return Err(RelayError::ServerConfig(format!(
                        "{name:?} is not an environment variable's name"
                    )));
                }
                Ok(format!("${name}"))
            }
        }
    }
}

/// A fresh password: 128 random bits, in hex (safe in a URL and a
/// nats-server file alike).
pub fn random_password() -> Result<String, RelayError> {
    let mut bytes = [0u8; 16];
    ring::rand::SecureRandom::fill(&ring::rand::SystemRandom::new(), &mut bytes)
        .map_err(|_| RelayError::ServerConfig("the system's random source failed".into()))?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// The `users` entries of a stage's parties: the daemon ([`DAEMON_USER`])
/// and each relay by its name. Each entry is one line of the nats-server
/// configuration syntax; what each may publish and subscribe is the whole
/// of the relay tier's trust (module documentation).
pub fn user_entries(
    stage: &str,
    daemon: &Secret,
    relays: &[(&str, Secret)],
) -> Result<Vec<String>, RelayError> {
    let subjects = Subjects::new(stage)?;
    let entry = |user: &str, password: &Secret, publish: &[String], subscribe: &[String]| {
        let list = |subjects: &[String]| {
            subjects
                .iter()
                .map(|s| format!("\"{s}\""))
                .collect::<Vec<_>>()
                .join(", ")
        };
        Ok::<_, RelayError>(format!(
            "{{user: \"{user}\", password: {}, permissions: {{publish: {{allow: [{}]}}, subscribe: {{allow: [{}]}}}}}}",
            password.written()?,
            list(publish),
            list(subscribe)
        ))
    };
    let mut entries = vec![entry(
        DAEMON_USER,
        daemon,
        &[subjects.out_all(), subjects.reply_all()],
        &[subjects.in_all()],
    )?];
    for (k, (relay, password)) in relays.iter().enumerate() {
        if !is_name(relay) || *relay == DAEMON_USER {
            return Err(RelayError::RelayName(relay.to_string()));
        }
        if relays[..k].iter().any(|(r, _)| r == relay) {
            return Err(RelayError::ServerConfig(format!(
                "relay {relay:?} is named twice"
            )));
        }
        entries.push(entry(
            relay,
            password,
            &[subjects.in_of(relay)],
            &[subjects.out_all(), format!("{}.>", subjects.inbox(relay))],
        )?);
    }
    Ok(entries)
}

/// A whole nats-server configuration: listening on `listen`
/// (`host:port`), and letting in only `entries` ([`user_entries`], and
/// any a test adds).
pub fn server_config(listen: &str, entries: &[String]) -> String {
    let mut text = format!("listen: {listen}\nauthorization {{\n  users = [\n");
    for entry in entries {
        text += &format!("    {entry}\n");
    }
    text += "  ]\n}\n";
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn credentials_come_out_of_the_address_and_are_never_shown() {
        let a = NatsAddress::parse_with("nats://hall:p%40ss@127.0.0.1:4222", None).unwrap();
        assert_eq!(a.servers, "nats://127.0.0.1:4222");
        assert_eq!(a.user(), Some("hall"));
        assert_eq!(a.password.as_deref(), Some("p@ss"));
        assert_eq!(a.shown(), "nats://hall@127.0.0.1:4222");
        assert!(!format!("{a:?}").contains("p@ss"));
        let from_env =
            NatsAddress::parse_with("nats://hall@127.0.0.1:4222", Some("env".into())).unwrap();
        assert_eq!(from_env.password.as_deref(), Some("env"));
        let open = NatsAddress::parse_with("nats://127.0.0.1:4222", Some("env".into())).unwrap();
        assert_eq!((open.user(), open.password.as_deref()), (None, None));
        let two =
            NatsAddress::parse_with("nats://u:p@a:1, nats://b:2", None).expect("a cluster's two");
        assert_eq!(two.servers, "nats://a:1,nats://b:2");
        assert!(NatsAddress::parse_with("nats://u:p@a:1,nats://v:q@b:2", None).is_err());
        assert!(NatsAddress::parse_with("nats://:p@a:1", None).is_err());
    }

    #[test]
    fn each_party_is_held_to_its_own_subjects() {
        let entries = user_entries(
            "demo",
            &Secret::Environment("D".into()),
            &[("hall", Secret::Literal("x1".into()))],
        )
        .unwrap();
        assert_eq!(
            entries,
            [
                "{user: \"puppetry\", password: $D, permissions: {publish: {allow: [\"puppetry.demo.out.>\", \"puppetry.demo.reply.>\"]}, subscribe: {allow: [\"puppetry.demo.in.>\"]}}}",
                "{user: \"hall\", password: \"x1\", permissions: {publish: {allow: [\"puppetry.demo.in.hall.>\"]}, subscribe: {allow: [\"puppetry.demo.out.>\", \"puppetry.demo.reply.hall.>\"]}}}",
            ]
        );
        let d = Secret::Literal("d".into());
        for bad in [
            vec![("puppetry", Secret::Literal("x".into()))],
            vec![("a.b", Secret::Literal("x".into()))],
            vec![("a", Secret::Literal("x\"".into()))],
            vec![("a", Secret::Environment("A-B".into()))],
            vec![
                ("a", Secret::Literal("x".into())),
                ("a", Secret::Literal("y".into())),
            ],
        ] {
            assert!(user_entries("demo", &d, &bad).is_err(), "{bad:?}");
        }
        assert_eq!(random_password().unwrap().len(), 32);
    }

    /// The bundled file is what [`user_entries`] makes for the demo stage
    /// and a relay `hall`, passwords from the environment.
    #[test]
    fn the_bundled_server_configuration_is_the_generated_one() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../config/nats/nats-server.conf"
        );
        let bundled = std::fs::read_to_string(path).expect("config/nats/nats-server.conf");
        let entries = user_entries(
            "demo",
            &Secret::Environment("PUPPETRY_NATS_DAEMON_PASSWORD".into()),
            &[(
                "hall",
                Secret::Environment("PUPPETRY_NATS_HALL_PASSWORD".into()),
            )],
        )
        .unwrap();
        let generated = server_config("127.0.0.1:4222", &entries);
        assert!(
            bundled.ends_with(&generated),
            "config/nats/nats-server.conf should end with:\n{generated}"
        );
    }
}
