//! Contacts to handles: a frame of a source's contacts grabs the puppet
//! under each new one (or moves a pad's cursor), moves what it holds and
//! lets go on lift; pins are handles no contact owns. Sources may be
//! limited to some puppets, and released whole when they go.

use super::*;

impl Stage {
    /// Applies one input frame: contacts land, move and lift.
    pub fn apply(&mut self, frame: &ContactFrame) {
        let source = frame.source.as_str();
        for contact in &frame.contacts {
            // A shared name: no allocation per contact.
            let key = (frame.source.clone(), contact.id);
            // Most stages have no pads: no lookup per contact then.
            if let Some(&pad) = (!self.pad_contacts.is_empty())
                .then(|| self.pad_contacts.get(&key))
                .flatten()
            {
                // An up never moves anything: it says where the finger
                // was last, or nothing (a page's up has no position).
                if contact.phase != Phase::Up {
                    self.move_cursor(pad, contact.position);
                }
                if contact.phase != Phase::Move {
                    self.pad_contacts.remove(&key);
                }
                if contact.phase != Phase::Down {
                    continue;
                }
            }
            match contact.phase {
                Phase::Down => {
                    // A repeated down without an up: the old grab ends first.
                    self.release(&key);
                    if let Some(pad) = self.pads.iter().position(|p| {
                        !self.puppets[p.puppet].removed && p.takes(source, contact.position)
                    }) {
                        self.pad_contacts.insert(key, pad);
                        self.move_cursor(pad, contact.position);
                        continue;
                    }
                    if let Some(grab) = self.grab(
                        Owner::Source(source.to_string()),
                        HandleKind::Contact,
                        contact.position,
                        Some(contact.id),
                    ) {
                        self.grabs.insert(key, grab);
                    }
                }
                Phase::Move => {
                    if let Some(&(puppet, handle)) = self.grabs.get(&key) {
                        let puppet = &mut self.puppets[puppet];
                        if let Some(h) = puppet
                            .handles
                            .iter_mut()
                            .find(|h| h.id == handle && h.target != contact.position)
                        {
                            h.target = contact.position;
                            puppet.moved = true;
                            if let Some(events) = &mut self.events {
                                events.push(StageEvent::Moved {
                                    puppet: puppet.id,
                                    handle,
                                    at: contact.position,
                                });
                            }
                        }
                    }
                }
                Phase::Up => self.release(&key),
            }
        }
    }

    /// Limits what a source's contacts and pins may grab to these puppets
    /// (by id), or lifts the limit (`None`).
    pub fn limit_source(&mut self, source: &str, puppets: Option<Vec<u32>>) {
        match puppets {
            Some(puppets) => {
                self.limits.insert(source.to_string(), puppets);
            }
            None => {
                self.limits.remove(source);
            }
        }
    }

    /// Lifts every contact of a source (it disconnected or vanished).
    pub fn release_source(&mut self, source: &str) {
        self.pad_contacts.retain(|k, _| k.0.as_str() != source);
        let keys: Vec<_> = self
            .grabs
            .keys()
            .filter(|k| k.0.as_str() == source)
            .cloned()
            .collect();
        for key in keys {
            self.release(&key);
        }
    }

    pub(crate) fn release(&mut self, key: &(SourceId, u32)) {
        if let Some((puppet, handle)) = self.grabs.remove(key) {
            self.remove_handle(puppet, handle);
        }
    }

    pub(crate) fn remove_handle(&mut self, puppet: usize, handle: u64) -> bool {
        let p = &mut self.puppets[puppet];
        let before = p.handles.len();
        p.handles.retain(|h| h.id != handle);
        let removed = p.handles.len() != before;
        p.handles_changed |= removed;
        if removed {
            p.handles_generation = p.handles_generation.wrapping_add(1);
        }
        if removed && let Some(events) = &mut self.events {
            events.push(StageEvent::Removed {
                puppet: p.id,
                handle,
            });
        }
        removed
    }

    /// A new handle at `at` on the topmost puppet there: a grid handle or
    /// joint within the grab radius, else the material point.
    pub(crate) fn grab(
        &mut self,
        owner: Owner,
        kind: HandleKind,
        at: DVec2,
        contact: Option<u32>,
    ) -> Option<(usize, u64)> {
        let radius = self.grab_radius();
        // On a puppet first, top to bottom; only when the contact is on
        // none, a hair outside one: the edge of the puppet on top must not
        // take a finger that is on the one below.
        let outline = self.width.min(self.height) * OUTLINE_REACH_FRACTION;
        let places = self.order.len();
        let passes = (0..places).rev().map(|place| (place, 0.0));
        for (place, outline) in passes.chain((0..places).rev().map(|place| (place, outline))) {
            let puppet = self.order[place];
            match self.puppets[puppet].reach(at, radius, outline) {
                // Full (`MAX_HANDLES_PER_PUPPET`): the finger holds nothing.
                Reach::Grip(..)
                    if self.puppets[puppet].handles.len()
                        >= puppetry_limits::contacts::MAX_HANDLES_PER_PUPPET =>
                {
                    return None;
                }
                Reach::Grip(grip, offset) => {
                    if let Owner::Source(source) = &owner
                        && let Some(puppets) = self.limits.get(source)
                        && !puppets.contains(&self.puppets[puppet].id)
                    {
                        return None;
                    }
                    let new = NewHandle {
                        owner,
                        kind,
                        grip,
                        at,
                        offset,
                        contact,
                    };
                    return Some((puppet, self.add_handle(puppet, new)));
                }
                Reach::Blocked => return None,
                Reach::Miss => {}
            }
        }
        None
    }

    /// Makes a handle with the next id; returns the id.
    pub(crate) fn add_handle(&mut self, puppet: usize, new: NewHandle) -> u64 {
        let id = self.next_handle;
        self.next_handle += 1;
        self.insert_handle(puppet, id, new)
    }

    /// Makes a handle with a given id (a new one, or a pin put back);
    /// returns the id.
    pub(crate) fn insert_handle(&mut self, puppet: usize, id: u64, new: NewHandle) -> u64 {
        let p = &mut self.puppets[puppet];
        if let Some(events) = &mut self.events {
            events.push(StageEvent::Made {
                puppet: p.id,
                handle: id,
                owner: new.owner.to_string(),
                contact: new.contact,
                kind: match new.kind {
                    HandleKind::Contact => "contact",
                    HandleKind::Pin => "pin",
                    HandleKind::Key => "key",
                }
                .to_string(),
                grip: p.grip_event(new.grip),
                at: new.at,
            });
        }
        p.handles.push(Handle {
            id,
            owner: new.owner,
            kind: new.kind,
            grip: new.grip,
            target: new.at,
            offset: new.offset,
        });
        p.handles_changed = true;
        p.handles_generation = p.handles_generation.wrapping_add(1);
        id
    }

    /// Pins what a contact landing at `at` would grab (a material point, a
    /// grid handle or a joint); returns (puppet, handle id).
    pub fn pin(&mut self, owner: Owner, at: DVec2) -> Option<(u32, u64)> {
        self.grab(owner, HandleKind::Pin, at, None)
            .map(|(puppet, id)| (puppet as u32, id))
    }

    /// Removes a pin; contacts cannot be unpinned.
    pub fn unpin(&mut self, puppet: u32, handle: u64) -> bool {
        let Some(p) = self.puppets.get(puppet as usize) else {
            return false;
        };
        if !p
            .handles
            .iter()
            .any(|h| h.id == handle && h.kind == HandleKind::Pin)
        {
            return false;
        }
        self.remove_handle(puppet as usize, handle)
    }
}
