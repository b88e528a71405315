//! Where an export may write, checked before anything is read or drawn.
//! A take is a performance that cannot be repeated and an animator's
//! folder holds work of their own, so an export refuses an output that is
//! the take itself (by any path or link), an output whose folder does not
//! exist (a video used to find out after drawing its first frame), and —
//! unless asked with `--force` — any file it would make that is already
//! there: the `.glb`, the video, the Spine JSON and its atlas and pictures,
//! or a PNG sequence's frames. Every file is then written under a fresh
//! name and renamed into place once whole ([`crate::write_new`]).

use std::path::{Path, PathBuf};

use crate::ExportError;

/// Whether an export may replace files that are already where it writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Overwrite {
    /// Refuse, naming the first file that is there (the default).
    #[default]
    Never,
    /// Replace them (`--force`).
    Replace,
}

fn refused(output: &Path, problem: String) -> ExportError {
    ExportError::Output {
        path: output.display().to_string(),
        problem,
    }
}

/// Refuses an output that is the take being exported: the same file, by
/// any path or link. `export T.take -o T.take` used to replace the take
/// with the export, exit 0.
pub fn refuse_the_take_itself(take: &Path, output: &Path) -> Result<(), ExportError> {
    use std::os::unix::fs::MetadataExt;
    let same = match (std::fs::metadata(take), std::fs::metadata(output)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    };
    if same {
        return Err(refused(
            output,
            format!(
                "is the take being exported ({}); give the export another name",
                take.display()
            ),
        ));
    }
    Ok(())
}

/// Refuses a file output whose folder is missing or not a folder. (A PNG
/// sequence's folder is made, with its parents, by the export.)
pub fn check_folder(output: &Path) -> Result<(), ExportError> {
    let folder = match output.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    };
    match std::fs::metadata(folder) {
        Ok(m) if m.is_dir() => Ok(()),
        Ok(_) => Err(refused(
            output,
            format!("{} is not a folder", folder.display()),
        )),
        Err(e) => Err(refused(
            output,
            format!("the folder {} cannot be used: {e}", folder.display()),
        )),
    }
}

/// Refuses, unless `overwrite` is [`Overwrite::Replace`], when one of
/// `files` is already there (a link counts, even one to nothing).
pub fn check_new(
    output: &Path,
    files: &[PathBuf],
    overwrite: Overwrite,
) -> Result<(), ExportError> {
    if overwrite == Overwrite::Replace {
        return Ok(());
    }
    let there: Vec<&PathBuf> = files
        .iter()
        .filter(|f| std::fs::symlink_metadata(f).is_ok())
        .collect();
    match there.as_slice() {
        [] => Ok(()),
        [one] if *one == output => Err(refused(
            output,
            "is already there; choose another name, or --force to replace it".into(),
        )),
        [first, ..] => Err(refused(
            output,
            format!(
                "the export would replace {} file(s) already there, {} first; choose another \
                 name, or --force to replace them",
                there.len(),
                first.display()
            ),
        )),
    }
}
