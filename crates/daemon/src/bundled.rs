//! The demo stage, its puppets and the stage files of `config/`, compiled
//! into the binary (the web client is compiled into the daemon crate), so an installed `puppetry` needs no checkout: `serve`
//! with no `--config` plays the bundled demo, `compare` and the benchmarks
//! find their figures. Stage files name their pictures and meshes by path,
//! so the bundle is unpacked once into a folder of its own (named by a hash
//! of its contents, so a new build never reuses an older bundle) and used
//! from there; saved weights land in that copy, never in a checkout.

use std::path::{Path, PathBuf};

use include_dir::{Dir, DirEntry, include_dir};

static CONFIG: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/../../config");
static ASSETS: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/../../assets");

/// The bundle could not be unpacked (a data folder that cannot be
/// written, a full disk).
#[derive(Debug, thiserror::Error)]
#[error("cannot unpack the bundled demo into {folder}: {source}")]
pub struct BundleError {
    folder: String,
    source: std::io::Error,
}

/// The folder holding the unpacked `config/` and `assets/`, unpacking them
/// on first use.
pub fn root() -> Result<PathBuf, BundleError> {
    let base = data_home().join("puppetry").join("bundled");
    let folder = base.join(format!("{:016x}", fingerprint()));
    if folder.join("config").is_dir() {
        return Ok(folder);
    }
    let failed = |source| BundleError {
        folder: folder.display().to_string(),
        source,
    };
    // Unpacked aside and renamed in whole, so two daemons starting at once
    // never see half a bundle.
    let aside = base.join(format!(".unpacking-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&aside);
    let unpacked = unpack(&CONFIG, &aside.join("config"))
        .and_then(|()| unpack(&ASSETS, &aside.join("assets")));
    if let Err(e) = unpacked {
        let _ = std::fs::remove_dir_all(&aside);
        return Err(failed(e));
    }
    if let Err(e) = std::fs::rename(&aside, &folder) {
        let _ = std::fs::remove_dir_all(&aside);
        // Another process unpacked the same bundle first: use theirs.
        if !folder.join("config").is_dir() {
            return Err(failed(e));
        }
    }
    Ok(folder)
}

/// The bundled demo stage file (a copy of `config/demo.toml`).
pub fn demo_stage() -> Result<PathBuf, BundleError> {
    Ok(root()?.join("config/demo.toml"))
}

/// The demo skeleton: the 15 bones of `config/skeleton.toml`, in the
/// coordinates `mesh_png` gives the demo picture (512 px, y up).
pub fn demo_skeleton() -> Result<puppetry_deform::skeleton::Skeleton, String> {
    let path = root()
        .map_err(|e| e.to_string())?
        .join("config/skeleton.toml");
    let config = puppetry_stage::config::StageConfig::load(&path).map_err(|e| e.to_string())?;
    let spec = config
        .puppets
        .first()
        .and_then(|p| p.skeleton.as_ref())
        .ok_or_else(|| format!("{}: no puppet with a skeleton", path.display()))?;
    let joints = spec
        .joints
        .iter()
        .map(|&[x, y]| glam::DVec2::new(x, y))
        .collect();
    puppetry_deform::skeleton::Skeleton::new(joints, spec.bones.clone())
        .map_err(|e| format!("{}: skeleton: {e}", path.display()))
}

/// The bundled demo picture.
pub fn demo_image() -> Result<PathBuf, BundleError> {
    Ok(root()?.join("assets/gingerbread/gingerbread.png"))
}

/// The bundled layered figure and its manipulation (see docs/measures.md).
pub fn layered_figure() -> Result<(PathBuf, PathBuf), BundleError> {
    let dir = root()?.join("assets/gingerbread-layers");
    Ok((
        dir.join("gingerbread-layers.mesh.json"),
        dir.join("handles.json"),
    ))
}

/// Every token the bundled stage files give (anonymous performers' and
/// people's): anyone who has read the README knows them, so a stage still
/// using one must not be served beyond this machine without a warning.
pub fn demo_tokens() -> Vec<String> {
    let mut tokens = Vec::new();
    for file in CONFIG.files() {
        let is_stage = file.path().extension().is_some_and(|e| e == "toml");
        let text = file.contents_utf8().filter(|_| is_stage);
        let name = file.path().display().to_string();
        // Parsed only (no file is read): the access section is all we need.
        let Some(config) =
            text.and_then(|t| crate::config::ShowConfig::parse(&name, t, Path::new("/")).ok())
        else {
            continue;
        };
        let access = config.access;
        for token in access
            .performer_tokens
            .into_iter()
            .chain(access.people.into_iter().map(|p| p.token))
        {
            if !tokens.contains(&token) {
                tokens.push(token);
            }
        }
    }
    tokens
}

fn data_home() -> PathBuf {
    if let Some(dir) = std::env::var_os("XDG_DATA_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(dir);
    }
    if let Some(home) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        return Path::new(&home).join(".local/share");
    }
    std::env::temp_dir()
}

fn unpack(dir: &Dir<'_>, to: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(to)?;
    for entry in dir.entries() {
        let name = entry
            .path()
            .file_name()
            .ok_or_else(|| std::io::Error::other("a bundled entry has no name"))?;
        match entry {
            DirEntry::Dir(d) => unpack(d, &to.join(name))?,
            DirEntry::File(f) => std::fs::write(to.join(name), f.contents())?,
        }
    }
    Ok(())
}

/// FNV-1a over every bundled path and its bytes.
fn fingerprint() -> u64 {
    fn walk(dir: &Dir<'_>, hash: &mut u64) {
        for entry in dir.entries() {
            let mut eat = |bytes: &[u8]| {
                for b in bytes {
                    *hash = (*hash ^ u64::from(*b)).wrapping_mul(0x100_0000_01b3);
                }
            };
            eat(entry.path().to_string_lossy().as_bytes());
            match entry {
                DirEntry::Dir(d) => walk(d, hash),
                DirEntry::File(f) => eat(f.contents()),
            }
        }
    }
    let mut hash = 0xcbf2_9ce4_8422_2325;
    walk(&CONFIG, &mut hash);
    walk(&ASSETS, &mut hash);
    hash
}
