//! The whole stage file as the daemon runs it: the stage's own part
//! (`puppetry_stage::config::StageConfig`: `[stage]`, puppets, pads), the
//! input sources (`puppetry_input::config`), and the sections only the
//! daemon reads — who may connect (`[access]`), show control (`[osc]`) and
//! relays (`[relay]`). Each layer parses the same text with its own
//! `deny_unknown_fields` structure and lets the others' sections through,
//! so a typo is still an error with its line, and the stage crate builds
//! no device or network setting. Checks that span layers (a person limited
//! to puppets that exist) are made here, where both are known.

use std::net::SocketAddr;
use std::ops::{Deref, DerefMut};
use std::path::Path;

use puppetry_input::config::{InputConfig, check_inputs};
use puppetry_stage::config::{ConfigError, MAX_CONNECTIONS, StageConfig, is_colour};
use serde::Deserialize;
use serde::de::IgnoredAny;

/// A stage file, every section parsed by the layer that owns it.
#[derive(Debug, Clone)]
pub struct ShowConfig {
    /// `[stage]`, `[[puppet]]`, `[[pad]]`: what the stage thread builds.
    pub stage_config: StageConfig,
    /// `[access]`: who may connect and what they may do (by default no
    /// one but viewers).
    pub access: Access,
    /// `[[input]]`: the input sources, in file order.
    pub inputs: Vec<InputConfig>,
    /// Show control over OSC (`docs/osc.md`); off without the section.
    pub osc: Option<OscConfig>,
    /// Publishing to relays over NATS (`docs/scaling.md`); off without
    /// the section.
    pub relay: Option<RelayConfig>,
}

/// The daemon's sections of the file; the stage's are let through.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Sections {
    #[serde(default)]
    access: Access,
    #[serde(default, rename = "input")]
    inputs: Vec<InputConfig>,
    #[serde(default)]
    osc: Option<OscConfig>,
    #[serde(default)]
    relay: Option<RelayConfig>,
    #[serde(default, rename = "stage")]
    _stage: Option<IgnoredAny>,
    #[serde(default, rename = "puppet")]
    _puppet: Option<IgnoredAny>,
    #[serde(default, rename = "pad")]
    _pad: Option<IgnoredAny>,
}

/// A show file reads as the stage file it contains (`config.puppets`,
/// `config.stage.width`): most of the daemon only needs that part, and the
/// stage thread is handed it as it is.
impl Deref for ShowConfig {
    type Target = StageConfig;
    fn deref(&self) -> &StageConfig {
        &self.stage_config
    }
}

impl DerefMut for ShowConfig {
    fn deref_mut(&mut self) -> &mut StageConfig {
        &mut self.stage_config
    }
}

impl ShowConfig {
    /// Reads and checks a stage file: every section, and every file it
    /// names.
    pub fn load(path: &Path) -> Result<ShowConfig, ConfigError> {
        let text = StageConfig::read_text(path)?;
        let folder = path.parent().unwrap_or(Path::new("."));
        let config = ShowConfig::parse(&path.display().to_string(), &text, folder)?;
        config.stage_config.check_files()?;
        for (i, input) in config.inputs.iter().enumerate() {
            if let InputConfig::Replay { file, .. } = input {
                let cap = puppetry_mesh::file::REPLAY_FILE;
                config
                    .stage_config
                    .check_file(format!("input[{i}].file"), "file", file, cap)?;
            }
        }
        Ok(config)
    }

    /// Parses a stage file's text; `file` names it in errors, `folder`
    /// anchors its relative paths.
    pub fn parse(file: &str, text: &str, folder: &Path) -> Result<ShowConfig, ConfigError> {
        let stage_config = StageConfig::parse(file, text, folder)?;
        // The toml crate's message is several lines: the line of the file
        // and a `^` under the fault. Kept whole, so the marker still points.
        let sections: Sections = toml::from_str(text).map_err(|e| ConfigError::Syntax {
            file: file.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        let invalid = |(field, problem): (String, String)| {
            ConfigError::Invalid(puppetry_mesh::FieldError::new(file, field, problem))
        };
        if sections.access.max_per_address > MAX_CONNECTIONS {
            return Err(invalid((
                "access.max_per_address".into(),
                format!("must be 1 to {MAX_CONNECTIONS}"),
            )));
        }
        check_inputs(&sections.inputs).map_err(invalid)?;
        if let Some(osc) = &sections.osc {
            check_osc(osc).map_err(invalid)?;
        }
        if let Some(relay) = &sections.relay {
            check_relay(relay).map_err(invalid)?;
        }
        check_access(&sections.access, &stage_config).map_err(invalid)?;
        Ok(ShowConfig {
            stage_config,
            access: sections.access,
            inputs: sections.inputs,
            osc: sections.osc,
            relay: sections.relay,
        })
    }
}

/// Checks `[relay]`; errors are `(field, problem)`.
fn check_relay(relay: &RelayConfig) -> Result<(), (String, String)> {
    let scheme = relay.nats.split_once("://").map(|(s, _)| s);
    if !matches!(scheme, Some("nats" | "tls")) {
        return Err((
            "relay.nats".into(),
            "must be a nats://host:port or tls://host:port address".into(),
        ));
    }
    let rate = relay.frame_rate;
    if !(rate == 0.0 || (1.0..=1000.0).contains(&rate)) {
        return Err((
            "relay.frame_rate".into(),
            "must be 0 (every solve) or 1 to 1000 frames a second".into(),
        ));
    }
    if let Some(name) = &relay.stage
        && (name.is_empty() || !name.chars().all(is_name_char))
    {
        return Err((
            "relay.stage".into(),
            "must be letters, digits, - and _ (one NATS subject token)".into(),
        ));
    }
    Ok(())
}

/// Who may connect and what they may do (`[access]`): named people with
/// roles and tokens, anonymous performer tokens, the WebSocket origins
/// allowed besides the daemon's own, and a cap per client address.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Access {
    /// Tokens of anonymous performers ("performer 1", "performer 2", …).
    #[serde(default)]
    pub performer_tokens: Vec<String>,
    /// Origins (`scheme://host[:port]`) whose pages may open the WebSocket
    /// besides the daemon's own; a client sending no Origin (not a
    /// browser) is always let in.
    #[serde(default)]
    pub allowed_origins: Vec<String>,
    /// Open WebSocket connections per client IP address at most (1 to
    /// `MAX_CONNECTIONS`; default 64).
    #[serde(default = "default_max_per_address")]
    pub max_per_address: usize,
    /// `[[access.person]]`: named people, each with a role and a token of
    /// their own.
    #[serde(default, rename = "person")]
    pub people: Vec<PersonConfig>,
}

impl Default for Access {
    fn default() -> Access {
        Access {
            performer_tokens: Vec::new(),
            allowed_origins: Vec::new(),
            max_per_address: default_max_per_address(),
            people: Vec::new(),
        }
    }
}

fn default_max_per_address() -> usize {
    64
}

/// `[[access.person]]`: someone who connects with their own token.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PersonConfig {
    /// Shown to everyone (the `people` list); unique, not blank.
    pub name: String,
    /// What they may do; with their token, this decides whatever role the
    /// hello asks for (but a viewer hello stays a viewer).
    pub role: AccessRole,
    /// What they say hello with; unique among people and performer tokens.
    pub token: String,
    /// `#RRGGBB`; default: the first palette colour no one connected has.
    #[serde(default)]
    pub colour: Option<String>,
    /// A performer limited to these puppets (by name); default: all.
    #[serde(default)]
    pub puppets: Option<Vec<String>>,
}

/// What a person may do (see `docs/protocol.md`, "Roles").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AccessRole {
    /// Everything: takes, painting, saving, key poses, performing.
    Director,
    /// Performing: contacts, pins, poses, cursors.
    Performer,
    /// Watching only.
    Viewer,
}

/// `scheme://host[:port]` with no path, as browsers send `Origin`.
fn is_origin(text: &str) -> bool {
    let Some((scheme, rest)) = text.split_once("://") else {
        return false;
    };
    !scheme.is_empty()
        && scheme
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
        && !rest.is_empty()
        && !rest.contains(['/', '?', '#', ' ', '@'])
}

/// The `[access]` section's checks: each problem names its field.
fn check_access(access: &Access, stage: &StageConfig) -> Result<(), (String, String)> {
    for (i, token) in access.performer_tokens.iter().enumerate() {
        if token.is_empty() {
            return Err((format!("access.performer_tokens[{i}]"), "empty".into()));
        }
        if access.performer_tokens[..i].contains(token) {
            return Err((
                format!("access.performer_tokens[{i}]"),
                "the same token is listed twice".into(),
            ));
        }
    }
    for (i, origin) in access.allowed_origins.iter().enumerate() {
        if !is_origin(origin) {
            return Err((
                format!("access.allowed_origins[{i}]"),
                format!(
                    "{origin:?} is not an origin like \"https://show.example\" (scheme://host[:port], no path)"
                ),
            ));
        }
    }
    if access.max_per_address == 0 {
        return Err(("access.max_per_address".into(), "must be at least 1".into()));
    }
    for (i, person) in access.people.iter().enumerate() {
        let field = |f: &str| format!("access.person[{i}].{f}");
        if person.name.trim().is_empty() {
            return Err((field("name"), "empty".into()));
        }
        if access.people[..i].iter().any(|p| p.name == person.name) {
            return Err((field("name"), "is used by another person".into()));
        }
        if person.token.is_empty() {
            return Err((field("token"), "empty".into()));
        }
        if access.people[..i].iter().any(|p| p.token == person.token) {
            return Err((field("token"), "is used by another person".into()));
        }
        if access.performer_tokens.contains(&person.token) {
            return Err((field("token"), "is also in access.performer_tokens".into()));
        }
        if let Some(colour) = &person.colour
            && !is_colour(colour)
        {
            return Err((field("colour"), format!("{colour:?} is not #RRGGBB")));
        }
        if let Some(puppets) = &person.puppets {
            if person.role != AccessRole::Performer {
                return Err((
                    field("puppets"),
                    "only a performer is limited to puppets".into(),
                ));
            }
            for (k, name) in puppets.iter().enumerate() {
                if !stage.puppets.iter().any(|p| &p.name == name) {
                    return Err((
                        field(&format!("puppets[{k}]")),
                        format!("no puppet is named {name:?}"),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// `[osc]`: show control over OSC/UDP (`docs/osc.md`): triggers in on
/// `listen`, the stage's state out to every `send` host `rate` times a
/// second, all under `prefix`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OscConfig {
    /// UDP address triggers are received on (none: no triggers).
    #[serde(default)]
    pub listen: Option<SocketAddr>,
    /// `host:port` of each receiver of the stage's state (names are
    /// resolved when the daemon starts, and again while they fail).
    #[serde(default)]
    pub send: Vec<String>,
    /// State updates a second.
    #[serde(default = "default_osc_rate")]
    pub rate: f64,
    /// What every address starts with.
    #[serde(default = "default_osc_prefix")]
    pub prefix: String,
}

/// `[relay]`: the stage published over NATS, for `puppetry relay`
/// processes to serve viewers and forward remote performers.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RelayConfig {
    /// The NATS server, `nats://host:port` (or `tls://…`: tokens of
    /// remote performers travel over it).
    pub nats: String,
    /// The stage's name on NATS (letters, digits, `-` and `_`); relays ask
    /// for it with `--stage`. Default: the stage file's name without `.toml`.
    #[serde(default)]
    pub stage: Option<String>,
    /// Frames a second of each puppet published to relays at most (an
    /// audience's display rate, for large audiences: a frame may then
    /// wait up to one interval); 0, the default: every solve, with no wait.
    #[serde(default)]
    pub frame_rate: f64,
}

impl ShowConfig {
    /// The stage's name on NATS (`[relay].stage`, or the file's stem).
    pub(crate) fn relay_stage_name(&self) -> String {
        let stem = Path::new(&self.stage_config.file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let named = self.relay.as_ref().and_then(|r| r.stage.clone());
        named.unwrap_or_else(|| {
            stem.chars()
                .map(|c| if is_name_char(c) { c } else { '_' })
                .collect()
        })
    }
}

/// Whether `c` may be in a stage's NATS name (one subject token).
pub(crate) fn is_name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '-' || c == '_'
}

/// Bounds of `[osc].rate`: below one a second a show desk looks frozen;
/// above 120 the updates outrun any display and flood the network.
pub(crate) const OSC_RATE: std::ops::RangeInclusive<f64> = 1.0..=120.0;

/// State updates (and key-blend steps) a second when the stage file
/// gives no `[osc].rate`.
pub const DEFAULT_OSC_RATE: f64 = 30.0;

fn default_osc_rate() -> f64 {
    DEFAULT_OSC_RATE
}

fn default_osc_prefix() -> String {
    "/puppetry".into()
}

/// Checks `[osc]`; errors are `(field, problem)`.
fn check_osc(osc: &OscConfig) -> Result<(), (String, String)> {
    if osc.listen.is_none() && osc.send.is_empty() {
        return Err((
            "osc".into(),
            "give `listen` (triggers in) or `send` (state out), or leave the section out".into(),
        ));
    }
    if !(osc.rate.is_finite() && OSC_RATE.contains(&osc.rate)) {
        return Err((
            "osc.rate".into(),
            format!(
                "must be between {} and {} updates a second",
                OSC_RATE.start(),
                OSC_RATE.end()
            ),
        ));
    }
    // OSC 1.0 forbids these in address parts (they are pattern syntax).
    let reserved = |c: char| " #*,?[]{}".contains(c) || !c.is_ascii_graphic();
    let p = &osc.prefix;
    if !p.starts_with('/') || p.ends_with('/') || p.contains("//") || p.chars().any(reserved) {
        return Err((
            "osc.prefix".into(),
            "must be an OSC address like \"/puppetry\": starts with '/', no trailing '/', \
             printable ASCII without space or any of # * , ? [ ] { }"
                .into(),
        ));
    }
    for (i, host) in osc.send.iter().enumerate() {
        if let Err(problem) = check_host_port(host) {
            return Err((format!("osc.send[{i}]"), problem));
        }
    }
    Ok(())
}

/// Checks a `host:port` (`[v6]:port` for IPv6 literals) without resolving.
pub(crate) fn check_host_port(text: &str) -> Result<(), String> {
    let expected = || format!("{text:?}: expected host:port, like \"127.0.0.1:9001\"");
    let (host, port) = text.rsplit_once(':').ok_or_else(expected)?;
    let host = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    if host.is_empty() || host.contains(':') && text.parse::<SocketAddr>().is_err() {
        return Err(expected());
    }
    match port.parse::<u16>() {
        Ok(p) if p > 0 => Ok(()),
        _ => Err(format!("{text:?}: the port must be 1 to 65535")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STAGE: &str = "[stage]\nwidth = 100\nheight = 100\n\
        [[puppet]]\nname = \"gingerbread\"\nimage = \"g.png\"\nmesh = \"g.mesh.json\"\nat = [50, 50]\n";

    fn parse(access: &str) -> Result<ShowConfig, String> {
        ShowConfig::parse("a.toml", &format!("{STAGE}{access}"), Path::new("/"))
            .map_err(|e| e.to_string())
    }

    #[test]
    fn the_relay_section_is_checked() {
        let config = parse("[relay]\nnats = \"nats://127.0.0.1:4222\"\n").unwrap();
        assert_eq!(config.relay.unwrap().nats, "nats://127.0.0.1:4222");
        assert_eq!(
            ShowConfig::parse(
                "my stage.toml",
                &format!("{STAGE}[relay]\nnats = \"nats://h:1\"\n"),
                Path::new("/")
            )
            .unwrap()
            .relay_stage_name(),
            "my_stage"
        );
        let named = parse("[relay]\nnats = \"tls://h:1\"\nstage = \"show-1\"\n").unwrap();
        assert_eq!(named.relay_stage_name(), "show-1");
        let bad = parse("[relay]\nnats = \"http://h:1\"\n").unwrap_err();
        assert!(bad.contains("relay.nats"), "{bad}");
        let bad = parse("[relay]\nnats = \"nats://h:1\"\nstage = \"a.b\"\n").unwrap_err();
        assert!(bad.contains("relay.stage"), "{bad}");
        let bad = parse("[relay]\nnats = \"nats://h:1\"\nframe_rate = 0.5\n").unwrap_err();
        assert!(bad.contains("relay.frame_rate"), "{bad}");
        let bad = parse("[relay]\nnats = \"nats://h:1\"\nstages = \"x\"\n").unwrap_err();
        assert!(bad.contains("stages"), "{bad}");
    }

    #[test]
    fn people_roles_and_defaults_are_read() {
        let config = parse(
            "[access]\nperformer_tokens = [\"demo\"]\nallowed_origins = [\"https://show.example\"]\n\
             [[access.person]]\nname = \"Ana\"\nrole = \"director\"\ntoken = \"a\"\ncolour = \"#E69F00\"\n\
             [[access.person]]\nname = \"Ben\"\nrole = \"performer\"\ntoken = \"b\"\npuppets = [\"gingerbread\"]\n",
        )
        .unwrap();
        let access = &config.access;
        assert_eq!(access.performer_tokens, ["demo"]);
        assert_eq!(access.max_per_address, 64);
        assert_eq!(access.people.len(), 2);
        assert_eq!(access.people[0].role, AccessRole::Director);
        assert_eq!(
            access.people[1].puppets.as_deref(),
            Some(&["gingerbread".to_string()][..])
        );
        // No [access] at all: nobody but viewers, the default cap.
        assert_eq!(parse("").unwrap().access.max_per_address, 64);
    }

    #[test]
    fn bad_access_entries_name_their_field() {
        let person = |fields: &str| format!("[[access.person]]\n{fields}\n");
        for (text, expected) in [
            (
                "[access]\nperformer_tokens = [\"\"]\n".to_string(),
                "access.performer_tokens[0]: empty",
            ),
            (
                person("name = \"Ana\"\nrole = \"director\"\ntoken = \"\""),
                "access.person[0].token: empty",
            ),
            (
                person("name = \"\"\nrole = \"director\"\ntoken = \"t\""),
                "access.person[0].name: empty",
            ),
            (
                format!(
                    "{}{}",
                    person("name = \"Ana\"\nrole = \"director\"\ntoken = \"t\""),
                    person("name = \"Ben\"\nrole = \"performer\"\ntoken = \"t\"")
                ),
                "access.person[1].token: is used by another person",
            ),
            (
                format!(
                    "{}{}",
                    person("name = \"Ana\"\nrole = \"director\"\ntoken = \"t\""),
                    person("name = \"Ana\"\nrole = \"performer\"\ntoken = \"u\"")
                ),
                "access.person[1].name: is used by another person",
            ),
            (
                format!(
                    "[access]\nperformer_tokens = [\"t\"]\n{}",
                    person("name = \"Ana\"\nrole = \"director\"\ntoken = \"t\"")
                ),
                "access.person[0].token: is also in access.performer_tokens",
            ),
            (
                person("name = \"Ana\"\nrole = \"director\"\ntoken = \"t\"\ncolour = \"orange\""),
                "access.person[0].colour: \"orange\" is not #RRGGBB",
            ),
            (
                person(
                    "name = \"Ana\"\nrole = \"performer\"\ntoken = \"t\"\npuppets = [\"ghost\"]",
                ),
                "access.person[0].puppets[0]: no puppet is named \"ghost\"",
            ),
            (
                person(
                    "name = \"Ana\"\nrole = \"viewer\"\ntoken = \"t\"\npuppets = [\"gingerbread\"]",
                ),
                "access.person[0].puppets: only a performer",
            ),
            (
                "[access]\nallowed_origins = [\"https://show.example/page\"]\n".to_string(),
                "access.allowed_origins[0]:",
            ),
            (
                "[access]\nmax_per_address = 0\n".to_string(),
                "access.max_per_address: must be at least 1",
            ),
        ] {
            let error = parse(&text).expect_err(&text);
            assert!(error.contains(expected), "{error}\nwanted: {expected}");
        }
        let error = parse(&person("name = \"Ana\"\nrole = \"boss\"\ntoken = \"t\"")).unwrap_err();
        assert!(error.contains("boss"), "{error}");
    }
}
