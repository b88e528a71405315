//! The scriptable commands behind `puppetry mesh`, `solve`, `compare` and `bench`: file
//! formats in and out, and errors that name the file and field at fault (and,
//! for a file of the wrong kind, what it is and what is taken instead); also
//! `--listen`'s forms and the URLs `serve` prints. `main.rs` only parses
//! arguments and reports.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::path::Path;

use glam::DVec2;
use serde::Deserialize;

use puppetry_bench::bench;
use puppetry_bench::compare::{self, CompareError, Comparison};
use puppetry_deform::ffd::{Basis, FfdError, MAX_GRID_HANDLES};
use puppetry_deform::skeleton::SkeletonError;
use puppetry_deform::{Anchor, Arap, ArapError, Steps};
use puppetry_mesh::build::{MeshOptions, Meshed, mesh_picture, mesh_png, triangulate};
use puppetry_mesh::polygon::Shape;
use puppetry_mesh::{Locator, Mesh, MeshError, json};

/// Why a command of this module failed; each message names the file (or
/// benchmark mesh) at fault, for `main.rs` to report as it is.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    /// A picture, polygon, mesh or handles file is unreadable, malformed or
    /// breaks a rule (the error names the file and field); also a bundled
    /// stage file that `bench --e2e` cannot load.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// The ARAP solver refused the mesh, the handles or the solve; the
    /// string is what is at fault: the mesh file if registering it failed,
    /// else the handles file (the mesh's name in `bench`).
    #[error("{file}: {0}", file = .1)]
    Solve(ArapError, String),
    /// `compare` could not run one of its methods.
    #[error("{file}: {source}")]
    Compare {
        /// The mesh file compared.
        file: String,
        /// Which method failed, and why.
        source: CompareError,
    },
    /// An lp-FFD case of `bench` failed; the string is the mesh's name.
    #[error("{file}: lp-FFD: {0}", file = .1)]
    Ffd(FfdError, String),
    /// A skeleton case of `bench` failed; the string is the mesh's name.
    #[error("{file}: skeleton: {0}", file = .1)]
    Skeleton(SkeletonError, String),
    /// A polygon or handles file is not a regular file (a folder, a FIFO),
    /// is past the mesh file's size cap, or failed to read.
    #[error(transparent)]
    File(#[from] puppetry_mesh::file::FileError),
    /// A file could not be opened or read: an input, whose first bytes are
    /// checked for its kind, or the bundled stage file of `bench --e2e`.
    #[error("{file}: cannot read: {source}")]
    Read {
        /// The file's path, as given.
        file: String,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// An output (a mesh, an SVG, the folder `compare --svg` writes into,
    /// `bench --e2e`'s temporary mesh) could not be created or written.
    #[error("{file}: cannot write: {source}")]
    Write {
        /// The output's path, as given.
        file: String,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A case of `bench --depth` failed; the string is the mesh's name.
    #[error("{file}: depth: {0}", file = .1)]
    Depth(bench::DepthBenchError, String),
    /// The bundled demo (its picture, stage or `compare` figure) could not
    /// be unpacked.
    #[error(transparent)]
    Bundle(#[from] puppetry_daemon::bundled::BundleError),
    /// The bundled demo skeleton, wanted by `bench`'s skeleton cases, did
    /// not load; the string says why.
    #[error("the bundled demo: {0}")]
    Demo(String),
    /// A file of the wrong kind: a picture given where a mesh or handles
    /// file is taken, or a picture other than a PNG (or a PDF) to `mesh`.
    #[error("{file}: this is {kind}; {expected}")]
    Kind {
        /// The file's path, as given.
        file: String,
        /// What the file is, in words ("a PNG picture", "not UTF-8 text").
        kind: &'static str,
        /// What is taken here instead, and how to make it.
        expected: &'static str,
    },
    /// `puppetry mesh` without `-o`, and the `NAME.mesh.json` it would
    /// write beside the input exists already (it is never replaced).
    #[error(
        "{file} exists already: give -o {file} to replace it, -o OTHER.mesh.json to write \
         elsewhere, or -o - for standard output"
    )]
    Exists {
        /// The mesh file that exists.
        file: String,
    },
}

/// What `puppetry mesh` takes, for errors about anything else.
const MESH_INPUTS: &str = "`puppetry mesh` takes a PNG picture (the shape is traced from its \
    alpha channel: convert the picture to PNG with a transparent background) or a polygon \
    .json file (docs/mesh-format.md)";

/// What `--mesh` takes.
const MESH_FILES: &str = "a mesh file (.mesh.json, docs/mesh-format.md) is expected here; \
    `puppetry mesh PICTURE.png -o NAME.mesh.json` makes one from a PNG picture";

/// What a handles file is.
const JSON_FILES: &str = "a JSON file is expected here";

/// `puppetry mesh`: a PNG (traced from its alpha) or a polygon JSON file to
/// a `.mesh.json`. Returns the mesh and what to warn the user about the
/// picture (a fully opaque one meshes as its rectangle).
pub fn mesh_command(
    input: &Path,
    vertices: Option<usize>,
    join: Option<f64>,
) -> Result<Meshed, CliError> {
    let options = MeshOptions {
        target_vertices: vertices,
        join,
    };
    // The contents decide, not the name: a PNG is meshed as a picture
    // whatever it is called, and another picture format is named as such
    // rather than failing as JSON that is not text.
    let kind = file_kind(input)?;
    let named_png = input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    match kind {
        Some(PNG) => return Ok(mesh_picture(input, &options)?),
        Some(kind) => {
            return Err(CliError::Kind {
                file: input.display().to_string(),
                kind,
                expected: MESH_INPUTS,
            });
        }
        // Not a picture format we know: the picture decoder says what is
        // wrong with a file that claims to be one.
        None if named_png => return Ok(mesh_picture(input, &options)?),
        None => {}
    }
    let name = input.display().to_string();
    let text = read(input, MESH_INPUTS)?;
    let shape = Shape::from_json(&name, &text)?;
    Ok(Meshed {
        mesh: triangulate(&name, &shape, &options)?,
        warnings: Vec::new(),
    })
}

/// The PNG entry of [`puppetry_stage::config::picture_kind`].
const PNG: &str = "a PNG picture";

/// What kind of picture (or document) `path` holds, by its first bytes;
/// None for anything else, such as text.
fn file_kind(path: &Path) -> Result<Option<&'static str>, CliError> {
    let mut head = [0u8; 16];
    let read = std::fs::File::open(path).and_then(|mut file| {
        use std::io::Read;
        let mut n = 0;
        while n < head.len() {
            match file.read(&mut head[n..])? {
                0 => break,
                got => n += got,
            }
        }
        Ok(n)
    });
    let n = read.map_err(|source| CliError::Read {
        file: path.display().to_string(),
        source,
    })?;
    Ok(puppetry_stage::config::picture_kind(&head[..n]))
}

/// A text file (a polygon or handles file, capped as a mesh file is: a
/// FIFO or `/dev/zero` is refused, not read forever); a picture or other
/// binary file is refused saying what it is and what `expected` here.
fn read(path: &Path, expected: &'static str) -> Result<String, CliError> {
    use puppetry_mesh::file::{self, FileError};
    match file::read_text(path, file::MESH_FILE) {
        Ok(text) => Ok(text),
        Err(FileError::NotText { file }) => Err(CliError::Kind {
            kind: file_kind(path).ok().flatten().unwrap_or("not UTF-8 text"),
            file,
            expected,
        }),
        Err(e) => Err(CliError::File(e)),
    }
}

/// A mesh file; a picture given instead is refused by name, with how to
/// mesh it.
pub fn load_mesh(path: &Path) -> Result<Mesh, CliError> {
    if let Some(kind) = file_kind(path)? {
        return Err(CliError::Kind {
            file: path.display().to_string(),
            kind,
            expected: MESH_FILES,
        });
    }
    Ok(Mesh::load(path)?)
}

/// Where `puppetry mesh` writes.
#[derive(Debug, Clone, PartialEq)]
pub enum MeshOutput {
    /// `-o -`.
    Stdout,
    /// `-o FILE`, replaced if it exists.
    File(std::path::PathBuf),
    /// No `-o`: `NAME.mesh.json` beside the input, never replacing a file.
    Beside(std::path::PathBuf),
}

impl MeshOutput {
    /// From `-o` (absent, `-`, or a file) and the input's name.
    pub fn new(input: &Path, output: Option<&Path>) -> MeshOutput {
        match output {
            Some(path) if path == Path::new("-") => MeshOutput::Stdout,
            Some(path) => MeshOutput::File(path.to_path_buf()),
            None => {
                let stem = input.file_stem().unwrap_or(input.as_os_str());
                let mut name = stem.to_os_string();
                name.push(".mesh.json");
                MeshOutput::Beside(input.with_file_name(name))
            }
        }
    }

    /// Writes the mesh's text; returns the file written (None for standard
    /// output).
    pub fn write(&self, text: &str) -> Result<Option<&Path>, CliError> {
        match self {
            MeshOutput::Stdout => {
                println!("{text}");
                Ok(None)
            }
            MeshOutput::File(path) => write(path, text).map(|()| Some(path.as_path())),
            MeshOutput::Beside(path) => {
                use std::io::Write;
                let file = path.display().to_string();
                // Created new: a mesh beside a picture may be the one a stage
                // file uses (the demo's is), and a default never replaces it.
                let created = std::fs::OpenOptions::new()
                    .write(true)
                    .create_new(true)
                    .open(path);
                let mut out = match created {
                    Ok(out) => out,
                    Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                        return Err(CliError::Exists { file });
                    }
                    Err(source) => return Err(CliError::Write { file, source }),
                };
                out.write_all(text.as_bytes())
                    .map_err(|source| CliError::Write { file, source })?;
                Ok(Some(path.as_path()))
            }
        }
    }
}

/// Writes `text` to `path`, replacing it; a failure names the file.
fn write(path: &Path, text: &str) -> Result<(), CliError> {
    std::fs::write(path, text).map_err(|source| CliError::Write {
        file: path.display().to_string(),
        source,
    })
}

/// The `--handles` file of `puppetry solve`.
#[derive(Debug, Deserialize)]
#[serde(
    deny_unknown_fields,
    expecting = "a handles object {\"handles\": [{\"vertex\": i, \"to\": [x, y]} | {\"point\": [x, y], \"to\": [x, y]}, …]}"
)]
struct HandlesFile {
    handles: Vec<HandleEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct HandleEntry {
    vertex: Option<i64>,
    point: Option<json::Point>,
    to: json::Point,
}

/// Parses a handles file against `mesh`: anchors and targets, in order.
pub fn parse_handles(
    file: &str,
    text: &str,
    mesh: &Mesh,
) -> Result<(Vec<Anchor>, Vec<DVec2>), CliError> {
    let parsed: HandlesFile = json::parse(file, text)?;
    let invalid = |field: String, problem: String| {
        CliError::Mesh(MeshError::Invalid(puppetry_mesh::FieldError::new(
            file, field, problem,
        )))
    };
    let locator = Locator::new(mesh);
    let mut anchors = Vec::with_capacity(parsed.handles.len());
    let mut targets = Vec::with_capacity(parsed.handles.len());
    for (h, entry) in parsed.handles.iter().enumerate() {
        let to = DVec2::from(entry.to.0);
        if !(to.is_finite() && to.abs().max_element() <= json::MAX_COORDINATE) {
            return Err(invalid(
                format!("handles[{h}].to"),
                format!(
                    "{} is too far out: coordinates must stay within ±{:e}",
                    json::show_point(to),
                    json::MAX_COORDINATE
                ),
            ));
        }
        let anchor = match (entry.vertex, entry.point) {
            (Some(v), None) => {
                if v < 0 || v as usize >= mesh.vertices().len() {
                    return Err(invalid(
                        format!("handles[{h}].vertex"),
                        format!(
                            "{v} is out of range (the mesh has {} vertices)",
                            mesh.vertices().len()
                        ),
                    ));
                }
                Anchor::Vertex(v as u32)
            }
            (None, Some(p)) => {
                let p = DVec2::from(p.0);
                let Some(location) = locator.locate(mesh, p) else {
                    return Err(invalid(
                        format!("handles[{h}].point"),
                        format!("{} is outside the mesh", json::show_point(p)),
                    ));
                };
                Anchor::Point {
                    triangle: location.triangle,
                    bary: location.bary,
                }
            }
            (Some(_), Some(_)) => {
                return Err(invalid(
                    format!("handles[{h}]"),
                    "give either \"vertex\" or \"point\", not both".into(),
                ));
            }
            (None, None) => {
                return Err(invalid(
                    format!("handles[{h}]"),
                    "needs a \"vertex\" index or a \"point\" [x, y]".into(),
                ));
            }
        };
        anchors.push(anchor);
        targets.push(to);
    }
    Ok((anchors, targets))
}

/// An SVG picture of the rest mesh (grey) under the deformed mesh (orange)
/// and the handle targets, so a person can see what `solve` did.
pub fn svg_of(mesh: &Mesh, pose: &[DVec2], targets: &[DVec2]) -> String {
    let all = mesh.vertices().iter().chain(pose).chain(targets);
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for p in all {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let margin = 0.05 * (hi - lo).max_element().max(1e-9);
    let (lo, hi) = (lo - DVec2::splat(margin), hi + DVec2::splat(margin));
    let size = hi - lo;
    // SVG is y-down; meshes are y-up.
    let at = |p: DVec2| format!("{:.3},{:.3}", p.x - lo.x, hi.y - p.y);
    let wire = |points: &[DVec2], colour: &str| {
        let mut path = String::new();
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| at(points[i as usize]));
            path.push_str(&format!("M{a}L{b}L{c}Z"));
        }
        format!(
            r#"<path d="{path}" fill="none" stroke="{colour}" stroke-width="{:.3}" stroke-linejoin="round"/>"#,
            size.max_element() / 800.0
        )
    };
    let dots: String = targets
        .iter()
        .map(|t| {
            format!(
                r##"<circle cx="{}" cy="{}" r="{:.3}" fill="#1565c0"/>"##,
                t.x - lo.x,
                hi.y - t.y,
                size.max_element() / 100.0
            )
        })
        .collect();
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {:.3} {:.3}" width="800">{}{}{}</svg>"#,
        size.x,
        size.y,
        wire(mesh.vertices(), "#bbbbbb"),
        wire(pose, "#e65100"),
        dots
    )
}

/// An SVG picture of a mesh's pieces, each filled in a colour of its own
/// (the Okabe–Ito palette, in turn), so a person sees which parts of a
/// picture would move apart.
pub fn pieces_svg(mesh: &Mesh) -> String {
    const COLOURS: [&str; 7] = [
        "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00", "#CC79A7",
    ];
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for p in mesh.vertices() {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let size = (hi - lo).max(DVec2::splat(1e-9));
    let at = |p: DVec2| format!("{:.3},{:.3}", p.x - lo.x, hi.y - p.y);
    let fills: String = mesh
        .pieces()
        .iter()
        .enumerate()
        .map(|(k, piece)| {
            let mut path = String::new();
            for &t in &piece.triangles {
                let [a, b, c] =
                    mesh.triangles()[t as usize].map(|i| at(mesh.vertices()[i as usize]));
                path.push_str(&format!("M{a}L{b}L{c}Z"));
            }
            format!(
                r#"<path d="{path}" fill="{}"><title>piece {}</title></path>"#,
                COLOURS[k % COLOURS.len()],
                k + 1
            )
        })
        .collect();
    format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {:.3} {:.3}" width="800">{fills}</svg>"#,
        size.x, size.y
    )
}

/// `puppetry solve`: the deformed vertices as `{"vertices": [[x, y], …]}`,
/// and optionally an SVG picture of the result.
pub fn solve_command(
    mesh_path: &Path,
    handles_path: &Path,
    step1_only: bool,
    svg: Option<&Path>,
) -> Result<String, CliError> {
    let mesh = load_mesh(mesh_path)?;
    let handles_name = handles_path.display().to_string();
    let (anchors, targets) = parse_handles(&handles_name, &read(handles_path, JSON_FILES)?, &mesh)?;
    let mesh_name = mesh_path.display().to_string();
    let mut arap = Arap::register(&mesh).map_err(|e| CliError::Solve(e, mesh_name))?;
    arap.compile(&anchors)
        .map_err(|e| CliError::Solve(e, handles_name.clone()))?;
    let steps = if step1_only {
        Steps::ScaleFree
    } else {
        Steps::Both
    };
    let pose = arap
        .update(&targets, steps)
        .map_err(|e| CliError::Solve(e, handles_name))?;
    if let Some(svg) = svg {
        write(svg, &svg_of(&mesh, pose, &targets))?;
    }
    let vertices: Vec<[f64; 2]> = pose.iter().map(|p| [p.x, p.y]).collect();
    Ok(serde_json::json!({ "vertices": vertices }).to_string())
}

/// A `--listen` value, parsed as the stage file's `listen` is.
pub use puppetry_stage::config::parse_listen;

/// Where a browser on this machine reaches a daemon listening on
/// `address`: itself, or loopback when it listens on every interface
/// (`0.0.0.0` or `[::]`, which no browser can open).
pub fn url_address(address: SocketAddr) -> SocketAddr {
    let ip: IpAddr = match address.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => Ipv4Addr::LOCALHOST.into(),
        IpAddr::V6(ip) if ip.is_unspecified() => Ipv6Addr::LOCALHOST.into(),
        ip => ip,
    };
    SocketAddr::new(ip, address.port())
}

/// What `serve` prints on starting: the URLs to open (usable ones: an
/// address every interface listens on is shown as loopback, and said) and
/// a warning when the stage is open beyond this machine with tokens anyone
/// who has read the README knows (`demo_tokens`, the bundled stages').
pub struct Serving {
    /// For standard output, in order: what is served where, then the
    /// performer and director URLs (with their tokens) when the stage has
    /// them.
    pub lines: Vec<String>,
    /// None unless the stage listens beyond loopback with one of the
    /// bundled demo tokens; then what to warn, and how to fix it.
    pub warning: Option<String>,
}

/// Where a stage is served from: what [`serving`] says depends on it.
pub struct Served<'a> {
    /// The stage file.
    pub file: &'a Path,
    /// Whether `file` is the bundled demo's unpacked copy (a folder named
    /// by a hash, replaced by the next build: no place for a user's edits).
    pub bundled: bool,
    /// The address the daemon listens on.
    pub address: SocketAddr,
    /// This machine's addresses other machines may reach it at (its
    /// interfaces but loopback), listed when it listens on all of them.
    pub network: &'a [IpAddr],
}

/// [`Serving`] for a stage served as `served` with `access`.
pub fn serving(
    served: &Served<'_>,
    access: &puppetry_daemon::config::Access,
    demo_tokens: &[String],
) -> Serving {
    let (file, address) = (served.file, served.address);
    let url = url_address(address);
    let mut first = format!("puppetry: serving {} at http://{url}/", file.display());
    if address.ip().is_unspecified() {
        first.push_str(&format!(" (listening on all interfaces, {address})"));
    }
    let mut lines = vec![first];
    if address.ip().is_unspecified() {
        let reachable: Vec<String> = served
            .network
            .iter()
            .filter(|ip| ip.is_ipv4() == address.is_ipv4() || address.is_ipv6())
            .map(|&ip| format!("http://{}/", SocketAddr::new(ip, address.port())))
            .collect();
        lines.push(if reachable.is_empty() {
            "  from other machines: this machine has no network address but loopback".into()
        } else {
            format!("  from other machines: {}", reachable.join("  "))
        });
    }
    lines.push(format!(
        "  show:    http://{url}/?view=show (the stage alone, for a projector)"
    ));
    if let Some(token) = access.performer_tokens.first() {
        lines.push(format!(
            "  perform: http://{url}/?role=performer&token={token}"
        ));
    }
    let director = access
        .people
        .iter()
        .find(|p| p.role == puppetry_daemon::config::AccessRole::Director);
    if let Some(director) = director {
        lines.push(format!(
            "  direct:  http://{url}/?role=director&token={}",
            director.token
        ));
    }
    let known: Vec<&str> = access
        .performer_tokens
        .iter()
        .chain(access.people.iter().map(|p| &p.token))
        .filter(|t| demo_tokens.contains(t))
        .map(String::as_str)
        .collect();
    // The bundled copy is replaced by the next build: edits go in a copy
    // of the user's own.
    let fix = if served.bundled {
        "Copy the demo stage to a stage file of your own (in a checkout, `cp \
         config/demo.toml config/mine.toml`), give it [access] tokens of your own \
         (config/README.md, \"Access\") and serve it with `--config config/mine.toml` \
         before serving on a network"
            .to_string()
    } else {
        format!(
            "Give [access] tokens of your own in {} (config/README.md, \"Access\") before \
             serving on a network",
            file.display()
        )
    };
    let warning = (!address.ip().is_loopback() && !known.is_empty()).then(|| {
        format!(
            "listening beyond this machine ({address}) with the bundled demo tokens ({}): \
             anyone on the network who has read the README can perform{}. {fix}, or listen \
             on 127.0.0.1.",
            known.join(", "),
            if director.is_some_and(|d| known.contains(&d.token.as_str())) {
                ", and direct (record, paint, save)"
            } else {
                ""
            },
        )
    });
    Serving { lines, warning }
}

/// This machine's network addresses but loopback (none when they cannot
/// be read), for [`Served::network`].
pub fn network_addresses() -> Vec<IpAddr> {
    let mut found: Vec<IpAddr> = if_addrs::get_if_addrs()
        .unwrap_or_default()
        .into_iter()
        .filter(|i| !i.is_loopback())
        .map(|i| i.ip())
        // Link-local IPv6 needs a zone no URL here carries.
        .filter(|ip| !matches!(ip, IpAddr::V6(v6) if v6.segments()[0] & 0xffc0 == 0xfe80))
        .collect();
    found.sort();
    found.dedup();
    found
}

/// Parses a `--grid` value, `COLUMNSxROWS` (e.g. `10x10`; `×` also works).
pub fn parse_grid(text: &str) -> Result<(usize, usize), String> {
    let expected = || format!("expected COLUMNSxROWS such as 10x10, got {text:?}");
    let (columns, rows) = text.split_once(['x', 'X', '×']).ok_or_else(expected)?;
    let count = |part: &str| part.trim().parse::<usize>().map_err(|_| expected());
    let (columns, rows) = (count(columns)?, count(rows)?);
    if columns < 2 || rows < 2 {
        return Err(format!(
            "{columns}x{rows}: a grid needs at least 2 handles in each direction"
        ));
    }
    if columns.saturating_mul(rows) > MAX_GRID_HANDLES {
        return Err(format!(
            "{columns}x{rows}: {} handles is more than the {MAX_GRID_HANDLES} the solver takes",
            columns.saturating_mul(rows)
        ));
    }
    Ok((columns, rows))
}

/// `puppetry compare`: the four methods of the lp-FFD paper's Table 1 on a
/// mesh and handles file (the bundled layered figure when `None`). With
/// `svg`, also draws each result to `DIR/<method>.svg`.
pub fn compare_command(
    figure: Option<(&Path, &Path)>,
    grid: (usize, usize),
    svg: Option<&Path>,
) -> Result<Comparison, CliError> {
    let bundled;
    let (mesh_path, handles_path) = match figure {
        Some(figure) => figure,
        None => {
            bundled = puppetry_daemon::bundled::layered_figure()?;
            (bundled.0.as_path(), bundled.1.as_path())
        }
    };
    let mesh = load_mesh(mesh_path)?;
    let handles_name = handles_path.display().to_string();
    let (anchors, targets) = parse_handles(&handles_name, &read(handles_path, JSON_FILES)?, &mesh)?;
    let comparison =
        compare::compare(&mesh, &anchors, &targets, grid.0, grid.1).map_err(|source| {
            CliError::Compare {
                file: mesh_path.display().to_string(),
                source,
            }
        })?;
    if let Some(dir) = svg {
        std::fs::create_dir_all(dir).map_err(|source| CliError::Write {
            file: dir.display().to_string(),
            source,
        })?;
        for m in &comparison.methods {
            let slug: String = m
                .method
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() {
                        c.to_ascii_lowercase()
                    } else {
                        '-'
                    }
                })
                .collect::<String>()
                .split('-')
                .filter(|w| !w.is_empty())
                .collect::<Vec<_>>()
                .join("-");
            write(
                &dir.join(format!("{slug}.svg")),
                &svg_of(&mesh, &m.pose, &targets),
            )?;
        }
    }
    Ok(comparison)
}

/// `puppetry bench`: the meshes to run, as (name, mesh).
pub fn bench_meshes(mesh: Option<&Path>, sizes: &[usize]) -> Result<Vec<(String, Mesh)>, CliError> {
    if let Some(path) = mesh {
        return Ok(vec![(path.display().to_string(), load_mesh(path)?)]);
    }
    let image = puppetry_daemon::bundled::demo_image()?;
    sizes
        .iter()
        .map(|&n| {
            let options = MeshOptions {
                target_vertices: Some(n),
                ..MeshOptions::default()
            };
            Ok((format!("gingerbread@{n}"), mesh_png(&image, &options)?))
        })
        .collect()
}

/// Runs the bench cases, printing each as it completes.
pub fn bench_command(
    meshes: &[(String, Mesh)],
    handle_counts: &[usize],
    json: bool,
    mut print: impl FnMut(&str),
) -> Result<Vec<bench::CaseResult>, CliError> {
    if !json {
        print(&bench::table_header());
    }
    let mut results = Vec::new();
    for (name, mesh) in meshes {
        for &handles in handle_counts {
            let frames = bench::frames_for(mesh.vertices().len());
            let result = bench::run_case(name, mesh, handles, frames)
                .map_err(|e| CliError::Solve(e, name.clone()))?;
            if json {
                print(&serde_json::to_string(&result).expect("plain numbers serialise"));
            } else {
                print(&bench::table_row(&result));
            }
            results.push(result);
        }
    }
    Ok(results)
}

/// Runs the rig cases (lp-FFD, both bases; the gingerbread skeleton on the
/// demo puppet's meshes only, since it is drawn for that picture), printing
/// each as it completes.
pub fn rig_bench_command(
    meshes: &[(String, Mesh)],
    with_skeleton: bool,
    json: bool,
    mut print: impl FnMut(&str),
) -> Result<Vec<bench::RigResult>, CliError> {
    if !json {
        print(&bench::rig_table_header());
    }
    let skeleton = puppetry_daemon::bundled::demo_skeleton().map_err(CliError::Demo)?;
    let mut results = Vec::new();
    let mut show = |result: bench::RigResult, results: &mut Vec<_>| {
        if json {
            print(&serde_json::to_string(&result).expect("plain numbers serialise"));
        } else {
            print(&bench::rig_table_row(&result));
        }
        results.push(result);
    };
    for (name, mesh) in meshes {
        let frames = bench::frames_for(mesh.vertices().len());
        for basis in [Basis::Bernstein, Basis::Lattice] {
            let result = bench::run_lp_ffd_case(name, mesh, basis, frames)
                .map_err(|e| CliError::Ffd(e, name.clone()))?;
            show(result, &mut results);
        }
        if with_skeleton {
            let result = bench::run_skeleton_case(name, mesh, &skeleton, frames)
                .map_err(|e| CliError::Skeleton(e, name.clone()))?;
            show(result, &mut results);
        }
    }
    Ok(results)
}

/// Runs the depth cases, printing each as it completes.
pub fn depth_bench_command(
    meshes: &[(String, Mesh)],
    json: bool,
    mut print: impl FnMut(&str),
) -> Result<Vec<bench::DepthResult>, CliError> {
    if !json {
        print(&bench::depth_table_header());
    }
    let mut results = Vec::new();
    for (name, mesh) in meshes {
        let frames = bench::frames_for(mesh.vertices().len()).max(500);
        let result = bench::run_depth_case(name, mesh, frames)
            .map_err(|e| CliError::Depth(e, name.clone()))?;
        if json {
            print(&serde_json::to_string(&result).expect("plain numbers serialise"));
        } else {
            print(&bench::depth_table_row(&result));
        }
        results.push(result);
    }
    Ok(results)
}

/// The stages `puppetry bench --e2e` runs: the demo stage, and the same
/// puppet meshed at about 10k vertices (written to a temporary file).
/// All listen on a free loopback port.
pub fn end_to_end_stages() -> Result<Vec<(String, puppetry_daemon::config::ShowConfig)>, CliError> {
    use puppetry_daemon::config::ShowConfig;
    use puppetry_stage::config::ConfigError;
    let load = |path: &Path| {
        ShowConfig::load(path).map_err(|e| match e {
            ConfigError::Read { file, source } => CliError::Read { file, source },
            other => CliError::Mesh(MeshError::Invalid(puppetry_mesh::FieldError::new(
                &path.display().to_string(),
                "stage",
                other.to_string(),
            ))),
        })
    };
    let mut demo = load(&puppetry_daemon::bundled::demo_stage()?)?;
    demo.stage.listen = std::net::SocketAddr::from(([127, 0, 0, 1], 0));
    let mut large = demo.clone();
    let mesh = mesh_png(
        &puppetry_daemon::bundled::demo_image()?,
        &MeshOptions {
            target_vertices: Some(10_000),
            ..MeshOptions::default()
        },
    )?;
    let file =
        std::env::temp_dir().join(format!("puppetry-bench-{}.mesh.json", std::process::id()));
    write(&file, &mesh.to_json())?;
    large.puppets[0].mesh = file;
    // Eight copies of the demo puppet, two rows of four, for four
    // performers with a finger on two puppets each.
    let mut many = demo.clone();
    let puppet = many.puppets[0].clone();
    many.puppets = (0..8)
        .map(|k| {
            let mut p = puppet.clone();
            p.name = format!("{}-{k}", puppet.name);
            p.at = [
                160.0 + 320.0 * (k % 4) as f64,
                180.0 + 360.0 * (k / 4) as f64,
            ];
            p.scale = 0.7;
            p
        })
        .collect();
    Ok(vec![
        ("demo stage".into(), demo),
        ("gingerbread@10000".into(), large),
        ("8 puppets".into(), many),
    ])
}

/// The performers `puppetry bench --e2e` drives on `stage`: up to four,
/// puppet `k` played by performer `k mod 4` with a finger at its centre.
pub fn end_to_end_performers(stage: &puppetry_stage::config::StageConfig) -> Vec<Vec<glam::DVec2>> {
    let performers = stage.puppets.len().min(4);
    (0..performers)
        .map(|j| {
            stage
                .puppets
                .iter()
                .skip(j)
                .step_by(performers)
                .map(|p| glam::DVec2::from(p.at))
                .collect()
        })
        .collect()
}

/// An evdev entry of the stage file: `input[index]`, its name, what device
/// it wants and of which kind.
struct DeviceEntry {
    index: usize,
    name: String,
    wanted: puppetry_input::device::DeviceMatch,
    kind: puppetry_input::device::DeviceKind,
}

/// The stage file's touch, pen and mouse entries, their paths resolved.
fn device_entries(config: Option<&puppetry_daemon::config::ShowConfig>) -> Vec<DeviceEntry> {
    use puppetry_input::config::{EvdevInput, InputConfig};
    use puppetry_input::device::DeviceKind;
    let Some(c) = config else {
        return Vec::new();
    };
    c.inputs
        .iter()
        .enumerate()
        .filter_map(|(index, input)| {
            let (kind, device, name, label) = match input {
                InputConfig::Touch(EvdevInput { device, name, .. }) => {
                    (DeviceKind::Touch, device, name, "touch")
                }
                InputConfig::Pen(EvdevInput { device, name, .. }) => {
                    (DeviceKind::Pen, device, name, "pen")
                }
                InputConfig::Mouse { device, name, .. } => {
                    (DeviceKind::Mouse, device, name, "mouse")
                }
                _ => return None,
            };
            let mut wanted = device.clone();
            wanted.path = wanted.path.map(|p| c.resolve(&p));
            let name = name.clone().unwrap_or_else(|| format!("{label}:{index}"));
            Some(DeviceEntry {
                index,
                name,
                wanted,
                kind,
            })
        })
        .collect()
}

/// `puppetry devices`: every input device in `dir` — name, path, kind,
/// ids, axes and ranges — and which entry of `config` (if given) would take
/// it; then the HID digitizers; then the raw MIDI ports in `midi_dir`;
/// then the entries no device took. Unreadable nodes are listed with what
/// to do about them.
pub fn devices_report(
    dir: &Path,
    midi_dir: &Path,
    config: Option<&puppetry_daemon::config::ShowConfig>,
) -> Result<String, puppetry_input::device::DeviceError> {
    use puppetry_input::device::scan;
    use std::fmt::Write;

    let entries = device_entries(config);
    let mut taken = vec![false; entries.len()];
    let mut out = String::new();
    let found = match scan(dir) {
        Ok(found) => found,
        Err(e) => {
            let _ = writeln!(
                out,
                "{e}\n(no input devices here: this machine has none, or a container does not share /dev/input)"
            );
            Vec::new()
        }
    };
    if found.is_empty() && dir.is_dir() {
        let _ = writeln!(out, "no input devices in {}", dir.display());
    }
    for (path, info) in &found {
        let info = match info {
            Ok(info) => info,
            Err(e) => {
                let _ = writeln!(out, "{}: not readable: {e}", path.display());
                continue;
            }
        };
        describe_device(&mut out, path, info);
        // An entry takes the first device that matches it.
        for (k, entry) in entries.iter().enumerate() {
            if !taken[k] && entry.kind == info.kind && entry.wanted.matches(info) {
                taken[k] = true;
                let _ = writeln!(out, "    used by input[{}] \"{}\"", entry.index, entry.name);
            }
        }
    }
    hid_report(&mut out, config);
    midi_report(&mut out, midi_dir, config);
    for (entry, taken) in entries.iter().zip(taken) {
        if !taken {
            let _ = writeln!(
                out,
                "input[{}] \"{}\" ({}, {}): no such device now; the daemon waits for it",
                entry.index, entry.name, entry.kind, entry.wanted
            );
        }
    }
    Ok(out)
}

/// One evdev device's lines: path, kind and name; ids; every absolute axis.
fn describe_device(out: &mut String, path: &Path, info: &puppetry_input::device::DeviceInfo) {
    use puppetry_input::device::DeviceKind;
    use std::fmt::Write;
    let _ = writeln!(
        out,
        "{}  {}{}  \"{}\"",
        path.display(),
        info.kind,
        match (info.kind, info.capabilities.direct) {
            (DeviceKind::Touch, true) => " (direct)",
            _ => "",
        },
        info.name
    );
    let _ = writeln!(
        out,
        "    id: bus {:04x} vendor {:04x} product {:04x}{}{}{}",
        info.id.bus,
        info.id.vendor,
        info.id.product,
        info.phys
            .as_ref()
            .map(|p| format!("  phys \"{p}\""))
            .unwrap_or_default(),
        info.uniq
            .as_ref()
            .map(|u| format!("  uniq \"{u}\""))
            .unwrap_or_default(),
        if info.capture {
            "  (evemu capture)"
        } else {
            ""
        },
    );
    for (code, axis) in &info.capabilities.absolute {
        let _ = writeln!(
            out,
            "    {:<18} {} .. {}{}",
            abs_name(*code),
            axis.min,
            axis.max,
            if axis.resolution > 0 {
                format!("  ({} per mm or radian)", axis.resolution)
            } else {
                String::new()
            }
        );
    }
}

/// The raw MIDI ports, each with the stage file's MIDI input that reads
/// it (by its path or its card's name); then the MIDI inputs whose port is
/// not here.
fn midi_report(
    out: &mut String,
    midi_dir: &Path,
    config: Option<&puppetry_daemon::config::ShowConfig>,
) {
    use puppetry_input::config::InputConfig;
    use puppetry_input::midi_port::{asound_dir_for, port_of_card, ports};
    use std::fmt::Write;
    let found = ports(midi_dir, &asound_dir_for(midi_dir));
    // Each raw-port input, with the port it reads now (a card's, looked up).
    let wanted: Vec<(usize, String, String, Option<&Path>)> = config
        .map(|c| {
            c.inputs
                .iter()
                .enumerate()
                .filter_map(|(i, input)| {
                    let InputConfig::Midi {
                        path, card, name, ..
                    } = input
                    else {
                        return None;
                    };
                    let (what, now) = match (path, card) {
                        (Some(path), _) => (path.display().to_string(), Some(path.as_path())),
                        (None, Some(card)) => (
                            format!("card {card:?}"),
                            port_of_card(&found, card).ok().map(|p| p.path.as_path()),
                        ),
                        (None, None) => return None,
                    };
                    Some((
                        i,
                        name.clone().unwrap_or_else(|| format!("midi:{i}")),
                        what,
                        now,
                    ))
                })
                .collect()
        })
        .unwrap_or_default();
    for port in &found {
        let _ = writeln!(
            out,
            "{}  midi  \"{}\"  card {} device {}",
            port.path.display(),
            port.name.as_deref().unwrap_or("?"),
            port.card,
            port.device
        );
        for (i, name, _, _) in wanted.iter().filter(|w| w.3 == Some(port.path.as_path())) {
            let _ = writeln!(out, "    used by input[{i}] \"{name}\"");
        }
    }
    for (i, name, what, now) in &wanted {
        if !now.is_some_and(|path| found.iter().any(|p| p.path == path)) {
            let _ = writeln!(
                out,
                "input[{i}] \"{name}\" (midi, {what}): no such port now; the daemon waits for it"
            );
        }
    }
}

/// The HID touch digitizers (hidapi), and which `kind = "hid"` entry of
/// `config` each would feed.
fn hid_report(out: &mut String, config: Option<&puppetry_daemon::config::ShowConfig>) {
    use puppetry_input::config::InputConfig;
    use std::fmt::Write;
    let hid_entries: Vec<(usize, String, puppetry_input::hid::HidSelector)> = config
        .map(|c| {
            c.inputs
                .iter()
                .enumerate()
                .filter_map(|(i, input)| match input {
                    InputConfig::Hid { device, name, .. } => Some((
                        i,
                        name.clone().unwrap_or_else(|| format!("hid:{i}")),
                        device.clone(),
                    )),
                    _ => None,
                })
                .collect()
        })
        .unwrap_or_default();
    let hids = match puppetry_input::hid::list_devices() {
        Ok(hids) => hids,
        Err(e) => {
            let _ = writeln!(out, "HID devices: {e}");
            return;
        }
    };
    let touch: Vec<_> = hids.iter().filter(|h| h.is_touch()).collect();
    if touch.is_empty() {
        let _ = writeln!(out, "no HID touch digitizers (hidraw)");
    }
    for h in &touch {
        let _ = writeln!(
            out,
            "{}  hid touch  \"{}\"\n    vendor_id {:#06x} product_id {:#06x}{}{}",
            h.path,
            h.product.as_deref().unwrap_or("?"),
            h.vendor_id,
            h.product_id,
            h.serial
                .as_ref()
                .map(|s| format!("  serial \"{s}\""))
                .unwrap_or_default(),
            match h.check_access() {
                Ok(()) => String::new(),
                Err(e) => format!("\n    not readable: {e}"),
            }
        );
        for (i, name, selector) in &hid_entries {
            if selector.matches(h) {
                let _ = writeln!(out, "    used by input[{i}] \"{name}\"");
            }
        }
    }
}

/// The kernel's name of an absolute axis.
fn abs_name(code: u16) -> String {
    use puppetry_input::evdev::*;
    let known = [
        (ABS_X, "ABS_X"),
        (ABS_Y, "ABS_Y"),
        (ABS_PRESSURE, "ABS_PRESSURE"),
        (ABS_TILT_X, "ABS_TILT_X"),
        (ABS_TILT_Y, "ABS_TILT_Y"),
        (ABS_MT_SLOT, "ABS_MT_SLOT"),
        (ABS_MT_TOUCH_MAJOR, "ABS_MT_TOUCH_MAJOR"),
        (ABS_MT_TOUCH_MINOR, "ABS_MT_TOUCH_MINOR"),
        (ABS_MT_WIDTH_MAJOR, "ABS_MT_WIDTH_MAJOR"),
        (ABS_MT_WIDTH_MINOR, "ABS_MT_WIDTH_MINOR"),
        (ABS_MT_ORIENTATION, "ABS_MT_ORIENTATION"),
        (ABS_MT_POSITION_X, "ABS_MT_POSITION_X"),
        (ABS_MT_POSITION_Y, "ABS_MT_POSITION_Y"),
        (ABS_MT_TOOL_TYPE, "ABS_MT_TOOL_TYPE"),
        (ABS_MT_BLOB_ID, "ABS_MT_BLOB_ID"),
        (ABS_MT_TRACKING_ID, "ABS_MT_TRACKING_ID"),
        (ABS_MT_PRESSURE, "ABS_MT_PRESSURE"),
        (ABS_MT_DISTANCE, "ABS_MT_DISTANCE"),
    ];
    known
        .iter()
        .find(|(c, _)| *c == code)
        .map_or_else(|| format!("ABS_{code:#04x}"), |(_, n)| n.to_string())
}
