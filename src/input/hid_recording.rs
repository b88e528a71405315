//! hid-recorder captures (placeholder).
