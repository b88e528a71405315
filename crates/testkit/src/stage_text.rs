//! Stage files the tests write: the `[stage]` header they share and the
//! gingerbread puppet's `[[puppet]]` section, written once here (they were
//! copied between a dozen test files), so a change to the stage file's
//! format is made in one place.
//!
//! ```
//! use puppetry_testkit::stage_text::{Gingerbread, STAGE};
//! let text = format!("{STAGE}{}", Gingerbread::new("g").at(400.0, 360.0).hand_pins());
//! assert!(text.contains("name = \"g\"") && text.contains("at = [400, 360]"));
//! ```

use std::fmt;
use std::path::{Path, PathBuf};

/// `[stage]` at the bundled demo's size, 1280 × 720.
pub const STAGE: &str = "[stage]\nwidth = 1280\nheight = 720\n";

/// The repository's gingerbread picture.
pub fn gingerbread_png() -> PathBuf {
    crate::root().join("assets/gingerbread/gingerbread.png")
}

/// The repository's gingerbread mesh.
pub fn gingerbread_mesh() -> PathBuf {
    crate::root().join("assets/gingerbread/gingerbread.mesh.json")
}

/// A `[[puppet]]` section of the gingerbread picture: at the stage's
/// centre, the repository's mesh, no pins, unless told otherwise.
#[derive(Debug, Clone)]
pub struct Gingerbread {
    name: String,
    at: [f64; 2],
    scale: Option<f64>,
    mesh: PathBuf,
    pins: Option<String>,
    more: String,
}

impl Gingerbread {
    /// The section of a puppet called `name`, as the struct says: at
    /// (640, 360), the repository's mesh, no `scale`, no pins.
    pub fn new(name: &str) -> Gingerbread {
        Gingerbread {
            name: name.to_string(),
            at: [640.0, 360.0],
            scale: None,
            mesh: gingerbread_mesh(),
            pins: None,
            more: String::new(),
        }
    }

    /// Sets its `at`, where on the stage it stands (stage units).
    pub fn at(mut self, x: f64, y: f64) -> Gingerbread {
        self.at = [x, y];
        self
    }

    /// Sets its `scale`; without this the section has no `scale` key, so
    /// the stage file's default applies.
    pub fn scale(mut self, scale: f64) -> Gingerbread {
        self.scale = Some(scale);
        self
    }

    /// Another mesh file (a copy a test may write beside).
    pub fn mesh(mut self, mesh: &Path) -> Gingerbread {
        self.mesh = mesh.to_path_buf();
        self
    }

    /// The demo's pins, on the two hands.
    pub fn hand_pins(self) -> Gingerbread {
        self.pins("[[168, 58], [344, 58]]")
    }

    /// Pins at these mesh points (`[[x, y], …]`).
    pub fn pins(mut self, pins: &str) -> Gingerbread {
        self.pins = Some(pins.to_string());
        self
    }

    /// Lines of its own after the section's keys (more keys, or its
    /// `[puppet.…]` tables).
    pub fn with(mut self, lines: &str) -> Gingerbread {
        self.more.push_str(lines);
        self.more.push('\n');
        self
    }
}

impl fmt::Display for Gingerbread {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "[[puppet]]")?;
        writeln!(f, "name = \"{}\"", self.name)?;
        writeln!(f, "image = \"{}\"", gingerbread_png().display())?;
        writeln!(f, "mesh = \"{}\"", self.mesh.display())?;
        writeln!(f, "at = [{}, {}]", self.at[0], self.at[1])?;
        if let Some(scale) = self.scale {
            writeln!(f, "scale = {scale}")?;
        }
        if let Some(pins) = &self.pins {
            writeln!(f, "pins = {pins}")?;
        }
        f.write_str(&self.more)
    }
}
