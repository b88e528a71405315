//! Integration tests of puppetry-export, on the demo puppet moved
//! synthetically ([`fixture`]). Checks that need Node run always and fail
//! with what to install when it is missing; checks that need Chromium too,
//! unless `PUPPETRY_BROWSER_TESTS=0` turns them off, like the workspace's
//! other browser tests; the video checks need ffmpeg.

mod common;
mod depth;
mod errors;
mod fixture;
mod frames;
mod gltf;
mod resample;
mod spine;
mod take;
mod video;
