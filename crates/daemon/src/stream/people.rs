//! Who is on the stage: the hello's token matched against the stage
//! file's `[access]` (in constant time, every token compared, so timing
//! tells nothing of how much of a guess was right), the identity it gives
//! (name, role, colour, puppets), and the `people` list everyone sees,
//! published on a watch channel whenever someone with a role joins or
//! leaves. Colours come from the Okabe–Ito palette, which stays distinct
//! for colour-blind eyes: a newcomer gets the first colour no one
//! connected has.

use std::sync::{Arc, Mutex};

use subtle::ConstantTimeEq;
use tokio::sync::watch;

use crate::config::{Access, AccessRole};
use crate::outputs::{Feed, Published, State};
use crate::protocol::{Person, PersonRole, Role, ServerMessage};

/// Okabe–Ito, without black (the stage's ink).
pub const PALETTE: [&str; 7] = [
    "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7",
];

/// Viewers' and input sources' colour.
pub const GREY: &str = "#999999";

/// What a token opens.
#[derive(Debug, Clone, PartialEq)]
pub enum Credential {
    /// A named person of `[[access.person]]` (index).
    Person(usize),
    /// One of `performer_tokens`.
    Anonymous,
}

/// The token of an `Authorization: Bearer TOKEN` header, if any: how
/// HTTP routes that need a person (exports, uploads) are given one.
pub fn bearer(headers: &axum::http::HeaderMap) -> Option<&str> {
    headers
        .get(axum::http::header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim)
}

/// The credential `token` opens, if any. Every token of the stage is
/// compared, each in constant time, whatever matched before.
pub fn credential(access: &Access, token: &str) -> Option<Credential> {
    let given = token.as_bytes();
    let mut found = None;
    for (i, person) in access.people.iter().enumerate() {
        if bool::from(person.token.as_bytes().ct_eq(given)) {
            found = Some(Credential::Person(i));
        }
    }
    for anonymous in &access.performer_tokens {
        if bool::from(anonymous.as_bytes().ct_eq(given)) && found.is_none() {
            found = Some(Credential::Anonymous);
        }
    }
    found
}

/// A connected client as the stage knows it.
#[derive(Debug, Clone, PartialEq)]
pub struct Identity {
    pub person: Person,
    pub role: Role,
    /// Ids of the puppets a limited performer plays; `None`: all.
    pub puppets: Option<Vec<u32>>,
}

/// The people on the stage, and the newest `people` message.
pub struct People {
    access: Access,
    puppet_names: Vec<String>,
    /// The stage's input sources, listed as role `device`.
    devices: Vec<Person>,
    connected: Mutex<Vec<Person>>,
    message: Feed,
}

impl People {
    pub fn new(config: &crate::config::ShowConfig, devices: Vec<String>) -> People {
        let devices = devices
            .into_iter()
            .map(|name| Person {
                owner: name.clone(),
                name,
                role: PersonRole::Device,
                colour: GREY.into(),
            })
            .collect();
        let people = People {
            access: config.access.clone(),
            puppet_names: config.puppets.iter().map(|p| p.name.clone()).collect(),
            devices,
            connected: Mutex::new(Vec::new()),
            message: watch::channel(Published::nothing()).0,
        };
        people.publish(&people.lock());
        people
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Person>> {
        self.connected.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn access(&self) -> &Access {
        &self.access
    }

    /// The newest `people` message, to watch.
    pub fn subscribe(&self) -> State {
        self.message.subscribe()
    }

    fn publish(&self, connected: &[Person]) {
        let people = connected.iter().chain(&self.devices).cloned().collect();
        self.message
            .send_replace(Published::of(ServerMessage::People { people }));
    }

    /// Who `owner` is, having said hello as `role` with `token` (already
    /// checked: `credential` is what it opened). Performers and directors
    /// join the `people` list until their [`Member`] is dropped.
    pub fn join(
        self: &Arc<Self>,
        owner: &str,
        asked: Role,
        credential: Option<Credential>,
    ) -> (Identity, Option<Member>) {
        let named = match &credential {
            Some(Credential::Person(i)) => self.access.people.get(*i),
            _ => None,
        };
        let role = match (asked, named, &credential) {
            (Role::Viewer, _, _) | (_, _, None) => Role::Viewer,
            (_, Some(p), _) => match p.role {
                AccessRole::Director => Role::Director,
                AccessRole::Performer => Role::Performer,
                AccessRole::Viewer => Role::Viewer,
            },
            (_, None, Some(_)) => Role::Performer,
        };
        let puppets = named.and_then(|p| p.puppets.as_ref()).map(|names| {
            names
                .iter()
                .filter_map(|n| self.puppet_names.iter().position(|p| p == n))
                .map(|i| i as u32)
                .collect()
        });
        let puppets = if role == Role::Performer {
            puppets
        } else {
            None
        };
        if role == Role::Viewer {
            let person = Person {
                owner: owner.to_string(),
                name: named.map_or_else(|| "viewer".to_string(), |p| p.name.clone()),
                role: PersonRole::Viewer,
                colour: GREY.into(),
            };
            return (
                Identity {
                    person,
                    role,
                    puppets,
                },
                None,
            );
        }
        let mut connected = self.lock();
        let name = match named {
            Some(p) => p.name.clone(),
            None => (1..)
                .map(|n| format!("performer {n}"))
                .find(|name| !connected.iter().any(|p| &p.name == name))
                .expect("a free number"),
        };
        let colour = match named.and_then(|p| p.colour.clone()) {
            Some(colour) => colour,
            None => first_free_colour(&connected),
        };
        let person = Person {
            owner: owner.to_string(),
            name,
            role: role.into(),
            colour,
        };
        connected.push(person.clone());
        self.publish(&connected);
        (
            Identity {
                person,
                role,
                puppets,
            },
            Some(Member {
                people: self.clone(),
                owner: owner.to_string(),
            }),
        )
    }

    fn leave(&self, owner: &str) {
        let mut connected = self.lock();
        connected.retain(|p| p.owner != owner);
        self.publish(&connected);
    }
}

/// The palette colour fewest connected people have, first in palette order
/// (so the first seven people all differ).
fn first_free_colour(connected: &[Person]) -> String {
    let uses = |c: &str| {
        connected
            .iter()
            .filter(|p| p.colour.eq_ignore_ascii_case(c))
            .count()
    };
    PALETTE
        .iter()
        .min_by_key(|c| uses(c))
        .expect("a palette")
        .to_string()
}

/// A place in the `people` list, given up when dropped (the connection
/// ended, however it ended).
pub struct Member {
    people: Arc<People>,
    owner: String,
}

impl Drop for Member {
    fn drop(&mut self) {
        self.people.leave(&self.owner);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn people() -> Arc<People> {
        let config = crate::config::ShowConfig::parse(
            "t.toml",
            "[stage]\nwidth = 10\nheight = 10\n[access]\nperformer_tokens = [\"demo\"]\n\
             [[access.person]]\nname = \"Ana\"\nrole = \"director\"\ntoken = \"ana\"\n\
             [[access.person]]\nname = \"Ben\"\nrole = \"performer\"\ntoken = \"ben\"\ncolour = \"#0072B2\"\n",
            Path::new("/"),
        )
        .unwrap();
        Arc::new(People::new(&config, vec!["grid-play".into()]))
    }

    #[test]
    fn tokens_open_their_person_and_nothing_else() {
        let p = people();
        assert_eq!(credential(p.access(), "ana"), Some(Credential::Person(0)));
        assert_eq!(credential(p.access(), "demo"), Some(Credential::Anonymous));
        for wrong in ["", "an", "anaa", "ANA", "demo "] {
            assert_eq!(credential(p.access(), wrong), None, "{wrong:?}");
        }
    }

    #[test]
    fn people_get_distinct_colours_and_leave_the_list() {
        let p = people();
        let (ana, ana_place) = p.join("client:1", Role::Performer, credential(p.access(), "ana"));
        assert_eq!(ana.role, Role::Director, "the person's role decides");
        let mut places = Vec::new();
        let mut colours = vec![ana.person.colour.clone()];
        for n in 2..6 {
            let (who, place) = p.join(
                &format!("client:{n}"),
                Role::Performer,
                Some(Credential::Anonymous),
            );
            assert_eq!(who.person.name, format!("performer {}", n - 1));
            colours.push(who.person.colour);
            places.push(place);
        }
        let (ben, _ben_place) = p.join("client:9", Role::Performer, credential(p.access(), "ben"));
        assert_eq!(ben.person.colour, "#0072B2", "a configured colour is kept");
        let mut distinct = colours.clone();
        distinct.sort();
        distinct.dedup();
        assert_eq!(distinct.len(), colours.len(), "{colours:?}");
        assert!(colours.iter().all(|c| PALETTE.contains(&c.as_str())));
        let listed: serde_json::Value = serde_json::from_str(&p.subscribe().borrow().text).unwrap();
        assert_eq!(listed["people"].as_array().unwrap().len(), 7);
        assert_eq!(listed["people"][6]["role"], "device");
        // A viewer is not listed; one who leaves gives up their colour.
        let (viewer, none) = p.join("client:10", Role::Viewer, credential(p.access(), "ana"));
        assert_eq!((viewer.role, none.is_none()), (Role::Viewer, true));
        drop(ana_place);
        let listed: serde_json::Value = serde_json::from_str(&p.subscribe().borrow().text).unwrap();
        assert_eq!(listed["people"].as_array().unwrap().len(), 6);
        let (next, _next_place) = p.join("client:11", Role::Performer, Some(Credential::Anonymous));
        assert_eq!(next.person.colour, ana.person.colour);
    }
}
