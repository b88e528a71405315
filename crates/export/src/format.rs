//! The export formats, one enum: the name `--format` and the export
//! route's `format=` take, the file each writes, whether a browser can
//! download it as one file and as what, and whether ffmpeg encodes it.
//! Every place that depends on the format matches on [`Format`], so a new
//! format that is not handled everywhere does not compile (there used to
//! be a catch-all arm that sent unknown names to the video encoder).

use std::fmt;
use std::str::FromStr;

/// An export format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Format {
    /// glTF 2.0 binary: the meshes, their pictures and morph-target
    /// animation.
    Glb,
    /// A folder of PNG frames, rendered here.
    Png,
    /// H.264 through ffmpeg.
    Mp4,
    /// ProRes 4444 with alpha through ffmpeg.
    Mov,
    /// VP9 with alpha through ffmpeg.
    Webm,
    /// Spine 4.x JSON with a deform timeline, and each puppet's picture.
    Spine,
}

/// A name that is not one of the formats.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0:?} is not one of glb, png, mp4, mov, webm, spine")]
pub struct UnknownFormat(pub String);

impl Format {
    /// Every format, in the order help texts list them.
    pub const ALL: [Format; 6] = [
        Format::Glb,
        Format::Png,
        Format::Mp4,
        Format::Mov,
        Format::Webm,
        Format::Spine,
    ];

    /// The name `--format` and `format=` take.
    pub fn name(self) -> &'static str {
        match self {
            Format::Glb => "glb",
            Format::Png => "png",
            Format::Mp4 => "mp4",
            Format::Mov => "mov",
            Format::Webm => "webm",
            Format::Spine => "spine",
        }
    }

    /// How a browser downloads it, as one file: its extension and MIME
    /// type; `None` for a PNG sequence (a folder: `puppetry export` only).
    pub fn download(self) -> Option<(&'static str, &'static str)> {
        match self {
            Format::Glb => Some(("glb", "model/gltf-binary")),
            Format::Mp4 => Some(("mp4", "video/mp4")),
            Format::Mov => Some(("mov", "video/quicktime")),
            Format::Webm => Some(("webm", "video/webm")),
            // The JSON needs its atlas and pictures: one zip of them.
            Format::Spine => Some(("zip", "application/zip")),
            Format::Png => None,
        }
    }

    /// What it is, for people: the page's list of downloads and `puppetry
    /// export --help`.
    pub fn label(self) -> &'static str {
        match self {
            Format::Glb => "glTF (.glb)",
            Format::Png => "PNG frames (a folder)",
            Format::Mp4 => "video (.mp4)",
            Format::Mov => "ProRes 4444 with alpha (.mov)",
            Format::Webm => "video with alpha (.webm)",
            Format::Spine => "Spine (.zip: JSON, atlas, pictures)",
        }
    }

    /// Whether ffmpeg encodes it (the output's extension must then be the
    /// format's name: ffmpeg picks its container by it).
    pub fn is_video(self) -> bool {
        match self {
            Format::Mp4 | Format::Mov | Format::Webm => true,
            Format::Glb | Format::Png | Format::Spine => false,
        }
    }
}

impl FromStr for Format {
    type Err = UnknownFormat;

    /// A format's name, in any case.
    fn from_str(text: &str) -> Result<Format, UnknownFormat> {
        Format::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(text))
            .ok_or_else(|| UnknownFormat(text.to_string()))
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_reads_back_and_others_are_refused() {
        for format in Format::ALL {
            assert_eq!(format.name().parse::<Format>(), Ok(format));
            assert_eq!(format.name().to_uppercase().parse::<Format>(), Ok(format));
        }
        assert_eq!(
            "avi".parse::<Format>().unwrap_err().to_string(),
            "\"avi\" is not one of glb, png, mp4, mov, webm, spine"
        );
    }
}
