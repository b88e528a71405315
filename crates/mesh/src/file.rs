//! Reading a file someone named, in bounded memory and time: the one way
//! every crate reads a file that a stage, key or take file (or the command
//! line) names. Only a regular file is read — a FIFO would block forever
//! and `/dev/zero` never ends — and at most its cap plus one byte, so a
//! file past its cap is refused by name with the limit, whatever its size
//! claims or becomes while read. The caps are in `puppetry_limits::files`.
//!
//! It lives here, in the mesh crate, because this is the lowest crate that
//! reads files (meshes and pictures) and every other crate that does
//! (input, stage, take, export, the daemon) already depends on it; the
//! limits crate stays free of dependencies, error types included.
//!
//! Writing a file a user keeps (a stage file a mapping is learnt into,
//! painted weights, keys, a recorded `.mid`) goes through
//! [`write_atomically`], so a crash leaves the old file or the new one.

use std::fs::File;
use std::io::Read;
use std::path::Path;

/// Why a named file was not read: which file, and which limit or check.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be inspected, opened or read (it is missing, not
    /// permitted, or reading it failed).
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The file's path, as given.
        file: String,
        /// What the operating system said; see [`FileError::io_kind`].
        source: std::io::Error,
    },
    /// The path names a folder, FIFO, device or socket: refused before it
    /// is opened, since opening a FIFO blocks and a device may never end.
    #[error("{file}: is {kind}, not a regular file; only regular files are read")]
    NotAFile {
        /// The file's path, as given.
        file: String,
        /// What it is instead, in words: "a folder", "a FIFO (named pipe)"…
        kind: &'static str,
    },
    /// The file is larger than its [`Cap`], by the size the file system
    /// gives or by what reading it yielded.
    #[error("{file}: larger than {limit} bytes, the most read from a {what} ({name})")]
    TooLarge {
        /// The file's path, as given.
        file: String,
        /// The cap, in bytes.
        limit: u64,
        /// What kind of file the limit is for ("stage file", "picture", …).
        what: &'static str,
        /// The limit's name in `puppetry_limits`, as `docs/limits.md` lists it.
        name: &'static str,
    },
    /// [`read_text`] read the file but its bytes are not UTF-8.
    #[error("{file}: not UTF-8 text")]
    NotText {
        /// The file's path, as given.
        file: String,
    },
}

impl FileError {
    /// The underlying I/O error's kind, when there is one (`NotFound` lets
    /// a caller treat a missing optional file as absent).
    pub fn io_kind(&self) -> Option<std::io::ErrorKind> {
        match self {
            FileError::Io { source, .. } => Some(source.kind()),
            _ => None,
        }
    }
}

/// A file's size cap, with its names for the error past it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cap {
    /// The most bytes read from such a file; a file with more is refused.
    pub bytes: u64,
    /// What kind of file it is, for the error ("stage file", "picture", …).
    pub what: &'static str,
    /// The limit's constant in `puppetry_limits::files`, named in the error
    /// so it can be looked up in `docs/limits.md`.
    pub name: &'static str,
}

use puppetry_limits::files as limits;

/// A stage file (TOML).
pub const STAGE_FILE: Cap = Cap {
    bytes: limits::MAX_STAGE_FILE_BYTES,
    what: "stage file",
    name: "MAX_STAGE_FILE_BYTES",
};
/// A `.mesh.json` rest mesh (or a shape file given to `puppetry mesh`).
pub const MESH_FILE: Cap = Cap {
    bytes: limits::MAX_MESH_FILE_BYTES,
    what: "mesh file",
    name: "MAX_MESH_FILE_BYTES",
};
/// A key-pose file.
pub const KEYS_FILE: Cap = Cap {
    bytes: limits::MAX_KEYS_FILE_BYTES,
    what: "key file",
    name: "MAX_KEYS_FILE_BYTES",
};
/// A replay input's recording or capture.
pub const REPLAY_FILE: Cap = Cap {
    bytes: limits::MAX_REPLAY_FILE_BYTES,
    what: "replay file",
    name: "MAX_REPLAY_FILE_BYTES",
};
/// A picture (PNG) as stored.
pub const PICTURE_FILE: Cap = Cap {
    bytes: limits::MAX_PICTURE_FILE_BYTES,
    what: "picture",
    name: "MAX_PICTURE_FILE_BYTES",
};

/// What a file that is not a regular file is, for the error.
fn kind_of(kind: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if kind.is_dir() {
        "a folder"
    } else if kind.is_fifo() {
        "a FIFO (named pipe)"
    } else if kind.is_char_device() {
        "a character device"
    } else if kind.is_block_device() {
        "a block device"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Opens `path` for reading if it is a regular file no larger than `cap`
/// (as the file system says now: a reader must still stop at the cap, see
/// [`read`]).
pub fn open(path: &Path, cap: Cap) -> Result<File, FileError> {
    open_checked(path, Some(cap))
}

/// Opens `path` for reading if it is a regular file, of any size: for
/// formats read record by record with each record bounded (takes).
pub fn open_regular(path: &Path) -> Result<File, FileError> {
    open_checked(path, None)
}

/// The file is checked before it is opened, since opening a FIFO blocks
/// until a writer comes, and again once open, in case it was swapped in
/// between.
fn open_checked(path: &Path, cap: Option<Cap>) -> Result<File, FileError> {
    let file = path.display().to_string();
    let io = |source| FileError::Io {
        file: file.clone(),
        source,
    };
    let check = |meta: std::fs::Metadata| {
        if !meta.file_type().is_file() {
            return Err(FileError::NotAFile {
                file: file.clone(),
                kind: kind_of(meta.file_type()),
            });
        }
        match cap {
            Some(cap) if meta.len() > cap.bytes => Err(too_large(&file, cap)),
            _ => Ok(()),
        }
    };
    check(std::fs::metadata(path).map_err(io)?)?;
    let handle = File::open(path).map_err(io)?;
    check(handle.metadata().map_err(io)?)?;
    Ok(handle)
}

fn too_large(file: &str, cap: Cap) -> FileError {
    FileError::TooLarge {
        file: file.to_string(),
        limit: cap.bytes,
        what: cap.what,
        name: cap.name,
    }
}

/// The bytes of the regular file `path`, refused past `cap` bytes: at most
/// `cap + 1` bytes are ever read, whatever the file does meanwhile.
pub fn read(path: &Path, cap: Cap) -> Result<Vec<u8>, FileError> {
    let file = path.display().to_string();
    let handle = open(path, cap)?;
    let hint = handle
        .metadata()
        .map(|m| m.len())
        .unwrap_or(0)
        .min(cap.bytes);
    let mut bytes = Vec::with_capacity(hint as usize);
    handle
        .take(cap.bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|source| FileError::Io {
            file: file.clone(),
            source,
        })?;
    if bytes.len() as u64 > cap.bytes {
        return Err(too_large(&file, cap));
    }
    Ok(bytes)
}

/// [`read`] as UTF-8 text.
pub fn read_text(path: &Path, cap: Cap) -> Result<String, FileError> {
    let bytes = read(path, cap)?;
    String::from_utf8(bytes).map_err(|_| FileError::NotText {
        file: path.display().to_string(),
    })
}

/// [`read_text`] handed to `parse` with the file's name for its errors:
/// how a capture or recording is opened, so each format keeps only its
/// parser.
pub fn parse_text<T, E: From<FileError>>(
    path: &Path,
    cap: Cap,
    parse: impl FnOnce(&str, &str) -> Result<T, E>,
) -> Result<T, E> {
    let text = read_text(path, cap)?;
    parse(&path.display().to_string(), &text)
}

/// A reader of the regular file `path` that fails with an error naming
/// the file and `cap` once more than `cap` bytes come out of it: for
/// formats read as a stream (line by line, or a PNG decoder).
pub fn reader(path: &Path, cap: Cap) -> Result<Capped, FileError> {
    Ok(Capped {
        inner: open(path, cap)?,
        left: cap.bytes,
        file: path.display().to_string(),
        cap,
    })
}

/// See [`reader`].
#[derive(Debug)]
pub struct Capped {
    inner: File,
    left: u64,
    file: String,
    cap: Cap,
}

impl Read for Capped {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // One byte past the cap is asked for, so reaching the cap exactly
        // (a file of the cap's size) is not mistaken for going past it.
        let want = buf.len().min(self.left.saturating_add(1) as usize);
        let n = self.inner.read(&mut buf[..want])?;
        if n as u64 > self.left {
            return Err(std::io::Error::new(
                std::io::ErrorKind::FileTooLarge,
                too_large(&self.file, self.cap).to_string(),
            ));
        }
        self.left -= n as u64;
        Ok(n)
    }
}

/// Seeking (which PNG decoding asks for) moves the cap's count with the
/// position, so what may still be read is always the cap less where the
/// reader stands.
impl std::io::Seek for Capped {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        let at = self.inner.seek(to)?;
        self.left = self.cap.bytes.saturating_sub(at);
        Ok(at)
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder,
/// synced, then renamed over it: readers see the old file or the new one,
/// never half of one.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    use std::sync::atomic::{AtomicU64, Ordering};
    // Unique per process and call, so two saves at once never share one.
    static SAVES: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .ok_or_else(|| std::io::Error::other("not a file path"))?
        .to_string_lossy();
    let save = SAVES.fetch_add(1, Ordering::Relaxed);
    let temporary = path.with_file_name(format!(".{name}.{}.{save}.tmp", std::process::id()));
    let result = (|| {
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: Cap = Cap {
        bytes: 8,
        what: "test file",
        name: "TINY",
    };

    #[test]
    fn dev_zero_and_folders_are_refused_at_once() {
        for path in ["/dev/zero", "/tmp"] {
            let e = read(Path::new(path), TINY).unwrap_err();
            assert!(matches!(e, FileError::NotAFile { .. }), "{e}");
            assert!(e.to_string().starts_with(path), "{e}");
        }
    }

    #[test]
    fn a_file_past_its_cap_is_refused_naming_the_limit() {
        let dir = std::env::temp_dir().join(format!("puppetry-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("nine");
        std::fs::write(&path, b"123456789").unwrap();
        let e = read(&path, TINY).unwrap_err();
        assert!(e.to_string().contains("TINY"), "{e}");
        let mut out = Vec::new();
        let e = reader(&path, Cap { bytes: 100, ..TINY })
            .unwrap()
            .read_to_end(&mut out);
        assert!(e.is_ok());
        std::fs::write(&path, b"12345678").unwrap();
        assert_eq!(read(&path, TINY).unwrap(), b"12345678");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
