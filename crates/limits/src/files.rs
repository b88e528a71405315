//! Files: bytes read from any file a stage, key or take file names, and the
//! pixels of a picture, checked before anything is allocated.
